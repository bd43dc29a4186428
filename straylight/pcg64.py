"""numpy's PCG64 streams in numba: SeedSequence hashing, PCG64 seeding, XSL-RR output and the
uniform draw ``(next64 >> 11) * 2^-53``, bit for bit the numbers of ``default_rng([seed, k]).random``
(used by :class:`straylight.rng.ChunkStreams`; tests/straylight/test_rng.py)."""
from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from materials.jit_cache import njit


@njit(cache=True, nogil=True)
def seed_states(words, n_words, out):
    """SeedSequence(entropy words).generate_state(4, uint64) -> PCG64 srandom, one row per chunk.

    words : (m, w) uint32 entropy as uint64 values, n_words (m,) used length; out : (m, 4) uint64
    (state hi, state lo, inc hi, inc lo). Constants and steps of numpy's SeedSequence (pool size 4)."""
    m32 = np.uint64(0xFFFFFFFF)
    mult_a = np.uint64(0x931E8875)
    mult_b = np.uint64(0x58F38DED)
    mix_l = np.uint64(0xCA01F9DD)
    mix_r = np.uint64(0x4973F715)
    s16 = np.uint64(16)
    s32 = np.uint64(32)
    one = np.uint64(1)
    s63 = np.uint64(63)
    mult_hi = np.uint64(2549297995355413924)
    mult_lo = np.uint64(4865540595714422341)
    pool = np.empty(4, np.uint64)
    st = np.empty(8, np.uint64)
    for r in range(words.shape[0]):
        nw = n_words[r]
        h = np.uint64(0x43B0D7E5)
        for i in range(4):  # hashmix of the entropy (0 past its end)
            v = words[r, i] if i < nw else np.uint64(0)
            v = (v ^ h) & m32
            h = (h * mult_a) & m32
            v = (v * h) & m32
            pool[i] = v ^ (v >> s16)
        for i_src in range(4):
            for i_dst in range(4):
                if i_src != i_dst:
                    v = (pool[i_src] ^ h) & m32
                    h = (h * mult_a) & m32
                    v = (v * h) & m32
                    v = v ^ (v >> s16)
                    x = (mix_l * pool[i_dst] - mix_r * v) & m32
                    pool[i_dst] = x ^ (x >> s16)
        for i_src in range(4, nw):
            for i_dst in range(4):
                v = (words[r, i_src] ^ h) & m32
                h = (h * mult_a) & m32
                v = (v * h) & m32
                v = v ^ (v >> s16)
                x = (mix_l * pool[i_dst] - mix_r * v) & m32
                pool[i_dst] = x ^ (x >> s16)
        hb = np.uint64(0x8B51F9DD)
        for i in range(8):  # generate_state(4, uint64): 8 uint32 words, little-endian pairs
            v = (pool[i % 4] ^ hb) & m32
            hb = (hb * mult_b) & m32
            v = (v * hb) & m32
            st[i] = v ^ (v >> s16)
        seed_hi = st[0] | (st[1] << s32)
        seed_lo = st[2] | (st[3] << s32)
        inc_hi0 = st[4] | (st[5] << s32)
        inc_lo0 = st[6] | (st[7] << s32)
        inc_hi = (inc_hi0 << one) | (inc_lo0 >> s63)
        inc_lo = (inc_lo0 << one) | one
        # pcg_setseq_128_srandom_r: state 0, step, add the seed, step
        s_hi, s_lo = _pcg_step(np.uint64(0), np.uint64(0), inc_hi, inc_lo, mult_hi, mult_lo)
        lo = s_lo + seed_lo
        s_hi = s_hi + seed_hi + (one if lo < s_lo else np.uint64(0))
        s_lo = lo
        s_hi, s_lo = _pcg_step(s_hi, s_lo, inc_hi, inc_lo, mult_hi, mult_lo)
        out[r, 0], out[r, 1], out[r, 2], out[r, 3] = s_hi, s_lo, inc_hi, inc_lo
    return out


@intrinsic
def _mulhi(typingctx, a, b):
    """High 64 bits of the 128-bit product of two uint64 (one LLVM i128 multiply: x86-64 ``mul``)."""
    sig = types.uint64(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        i128 = ir.IntType(128)
        prod = builder.mul(builder.zext(args[0], i128), builder.zext(args[1], i128))
        return builder.trunc(builder.lshr(prod, ir.Constant(i128, 64)), ir.IntType(64))

    return sig, codegen


@njit(cache=True, nogil=True, inline="always")
def _pcg_step(s_hi, s_lo, inc_hi, inc_lo, mult_hi, mult_lo):
    """state <- state * MULT + inc (mod 2^128)."""
    lo = s_lo * mult_lo
    hi = _mulhi(s_lo, mult_lo) + s_lo * mult_hi + s_hi * mult_lo
    lo2 = lo + inc_lo
    hi = hi + inc_hi + (np.uint64(1) if lo2 < lo else np.uint64(0))
    return hi, lo2


@njit(cache=True, nogil=True)
def fill_uniforms(states, rows, per_chunk, width, out):
    """out[i, :] <- the next ``width`` uniforms of the generator of chunk ``rows[i] // per_chunk``
    (rows of one chunk contiguous and in order, as gen.random((rows, width)) fills them)."""
    mult_hi = np.uint64(2549297995355413924)
    mult_lo = np.uint64(4865540595714422341)
    s11 = np.uint64(11)
    s58 = np.uint64(58)
    s63 = np.uint64(63)
    unit = 1.0 / 9007199254740992.0
    n = out.shape[0]
    i = 0
    while i < n:
        c = rows[i] // per_chunk
        s_hi, s_lo, inc_hi, inc_lo = states[c, 0], states[c, 1], states[c, 2], states[c, 3]
        while i < n and rows[i] // per_chunk == c:
            for k in range(width):
                s_hi, s_lo = _pcg_step(s_hi, s_lo, inc_hi, inc_lo, mult_hi, mult_lo)
                x = s_hi ^ s_lo
                rot = s_hi >> s58
                x = (x >> rot) | (x << ((np.uint64(64) - rot) & s63))  # rotr64
                out[i, k] = np.float64(x >> s11) * unit
            i += 1
        states[c, 0], states[c, 1] = s_hi, s_lo
    return out
