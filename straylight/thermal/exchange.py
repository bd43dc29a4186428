"""Radiative distribution factors (Mahan, *Radiation Heat Transfer: A Statistical Approach*,
2002, ch. 5-6): D_ij is the fraction of the band power emitted by part i that part j absorbs
after any number of reflections and transmissions (CONTRACTS §7.2).

Every side of a part that absorbs emits (Kirchhoff, CONTRACTS §7), at the part's ``temperature_k``
(300 K where it has none): its front, and the back of a one-sided part (an analytic surface or an
open mesh: model.ThermalScene.one_sided) with the back material's emissivity; a closed solid's back
is inside it. Each side emits from uniform points, directions with density eps(theta) cos(theta) /
(pi eps_h) of that side (exact, so all rays of a side weigh the same), traced at each sub-band's
wavelength with rays in proportion to the side's band power there. At every hit the walk books the power it removes (weight x (1 -
throughput) and what Russian roulette removes or adds) to the part hit; absorbers and detectors take
everything. What a path still carries at the event cap (``walk.MAX_EVENTS``, reached only in closed
mirror cavities) is booked to no part: it is reported as ``truncated`` (exchange_details.json) and
warned above 1 % of a part's emission, as ``trace`` warns for its max_events (a perfect mirror was
booked 4.3 % absorbed). So each row plus ``escaped`` plus ``truncated`` is exactly 1 and
the estimate of D_ij is unbiased (roulette is). The band value is the emitted-power-weighted mean
over sub-bands and sides; ``area_mm2`` is the emitting area (both sides of a one-sided part) and
``emissivity`` the hemispherical band emissivity averaged over it, so that eps_i A_i D_ij =
eps_j A_j D_ji at equal temperatures (reciprocity).
"""
from __future__ import annotations

import csv
import io
import itertools
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import atomicio
from straylight.frames import data_frame
from straylight.run_checks import TRUNCATION_WARN_FRACTION, TruncationWarning
from straylight.thermal.tables import plot_matrix
from straylight.thermal.model import sub_bands
from straylight.thermal.planck import band_radiance_w_m2_sr, check_band
from straylight.thermal.sampling import AreaSampler, emission_rays
from straylight.rng import BatchDraws, stream_chunk
from straylight.thermal.walk import batches_of, chunk_counts, walk

DEFAULT_TEMPERATURE_K = 300.0


@dataclass
class ExchangeResult:
    band_um: tuple
    names: list
    area_mm2: np.ndarray
    emissivity: np.ndarray
    d: np.ndarray  # (P, P)
    stderr: np.ndarray  # (P, P)
    escaped: np.ndarray  # (P,)
    escaped_stderr: np.ndarray
    rays: int
    seed: int
    temperatures_k: np.ndarray
    truncated: np.ndarray | None = None  # (P,) fraction of each part's emission cut at the event cap

    def couplings_m2(self) -> np.ndarray:
        """eps_i A_i D_ij in m^2."""
        return (self.emissivity * self.area_mm2 * 1e-6)[:, None] * self.d

    def to_json_dict(self) -> dict:
        """exchange.json (CONTRACTS §7.2), exactly its keys."""
        return {"band_um": [float(self.band_um[0]), float(self.band_um[1])],
                "parts": [{"name": n, "area_mm2": float(a), "emissivity": float(e)}
                          for n, a, e in zip(self.names, self.area_mm2, self.emissivity)],
                "distribution_factors": self.d.tolist(), "stderr": self.stderr.tolist(),
                "escaped": self.escaped.tolist()}

    def to_pandas(self):
        """D_ij as a DataFrame: rows emitting parts, columns absorbing parts and ``escaped`` (pandas is optional)."""
        rows = [{"part": n, **dict(zip(self.names, map(float, d))), "escaped": float(e)}
                for n, d, e in zip(self.names, self.d, self.escaped)]
        return data_frame(rows, ["part", *self.names, "escaped"]).set_index("part")

    def plot(self, path=None, ax=None):
        """The matrix D_ij (log colour scale)."""
        return plot_matrix(self.d, self.names, f"distribution factors D_ij, {self.band_um[0]:g}-{self.band_um[1]:g} um",
                           path, ax)

    def couplings_csv(self) -> str:
        """Matrix CSV: a header ``part,<name j>...`` and one row per emitting part i of eps_i A_i D_ij (m^2)."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["part"] + list(self.names))
        for name, row in zip(self.names, self.couplings_m2()):
            w.writerow([name] + [f"{x:.9g}" for x in row])
        return buf.getvalue()

    def write(self, directory) -> None:
        directory = Path(directory)
        atomicio.write_json(directory / "exchange.json", self.to_json_dict())
        atomicio.write_text(directory / "couplings.csv", self.couplings_csv())
        atomicio.write_json(directory / "exchange_details.json", {
            "rays": self.rays, "seed": self.seed, "escaped_stderr": self.escaped_stderr.tolist(),
            "truncated": (self.truncated if self.truncated is not None else np.zeros(len(self.names))).tolist(),
            "temperatures_k": dict(zip(self.names, map(float, self.temperatures_k))),
            "couplings_m2": self.couplings_m2().tolist()})

    def summary(self) -> str:
        lines = [f"distribution factors D_ij, {self.band_um[0]:g}-{self.band_um[1]:g} um ({self.rays} rays)"]
        for i, n in enumerate(self.names):
            top = np.argsort(-self.d[i])[:3]
            parts = ", ".join(f"{self.names[j]} {self.d[i, j]:.4g}" for j in top if self.d[i, j] > 0)
            lines.append(f"  {n} (eps {self.emissivity[i]:.4g}): {parts}; escaped {self.escaped[i]:.4g}")
        return "\n".join(lines)


def exchange(ts, band_um, n_rays: int, seed: int = 0) -> ExchangeResult:
    """D_ij of every part of ``ts`` (straylight.thermal.model.ThermalScene) in the band.

    Every absorbing side emits (CONTRACTS §7): a part's front, and the back of a one-sided part
    (``ts.one_sided``: an analytic surface or an open mesh) with its back material's emissivity. Each
    (sub-band, side) of part i is a stratum with rays in proportion to its emitted power, so row i is
    the fraction of the power both sides emit; ``area_mm2`` counts both sides of a one-sided part and
    ``emissivity`` is their mean (:func:`side_emission`), so that eps_i A_i D_ij = eps_j A_j D_ji."""
    lo, hi = check_band(*band_um)
    P = ts.n_parts
    temps = np.where(ts.temperature_k > 0, ts.temperature_k, DEFAULT_TEMPERATURE_K)
    bands = sub_bands(lo, hi, ts.wavelength_dependent())
    emitted, band_eps, area_mm2 = side_emission(ts, bands, temps)
    K = len(bands)
    n_sides = 2 if np.any(ts.one_sided) else 1  # streams of the backs after the fronts'
    emitters = [p for p in range(P) if band_eps[p] > 0]
    per_part = max(2, int(n_rays) // max(1, len(emitters)))
    d = np.zeros((P, P))
    var = np.zeros((P, P))
    esc = np.ones(P)
    esc_var = np.zeros(P)
    cut = np.zeros(P)
    for i in emitters:
        share = emitted[:, i, :] / emitted[:, i, :].sum()  # (K, 2): the strata of part i
        sampler = AreaSampler.of_part(ts, i)
        esc[i] = 0.0
        for (k, (_, _, lam)), side in itertools.product(enumerate(bands), range(2)):
            n_ks = _stratum_rays(per_part, share[k, side])
            if n_ks == 0:
                continue
            s1, s2 = np.zeros(P + 2), np.zeros(P + 2)
            counts = chunk_counts(n_ks)
            stream = side * P * K + i * K + k
            ids = [stream_chunk(c, stream, n_sides * P * K) for c in range(len(counts))]
            for batch_ids, batch_counts in batches_of(ids, counts):
                a, b = _emit_batch(ts, ts.sides_at(lam), i, sampler, BatchDraws(seed, batch_ids, batch_counts),
                                   side)
                s1 += a
                s2 += b
            mean = s1 / n_ks
            v = np.maximum(s2 - s1 * s1 / n_ks, 0.0) / (n_ks * (n_ks - 1.0))
            w = share[k, side]
            d[i] += w * mean[:P]
            var[i] += w ** 2 * v[:P]
            esc[i] += w * mean[P]
            esc_var[i] += w ** 2 * v[P]
            cut[i] += w * mean[P + 1]
    _warn_truncated(cut, ts.part_names)
    return ExchangeResult((lo, hi), list(ts.part_names), area_mm2, band_eps, d, np.sqrt(var), esc, np.sqrt(esc_var),
                          int(n_rays), int(seed), temps, truncated=cut)


def side_emission(ts, bands, temps):
    """What each part's sides emit: (per unit area, W m^-2 (K, P, 2): pi B_band(T) eps_h of each
    sub-band, part and side, 0 for the back of a closed solid), the band emissivity (P,) and the
    emitting area (P,) mm^2 of each part. The emitting sides are the front, and the back of a one-sided
    part (``ts.one_sided``); the area counts them (twice the part's area for a one-sided part) and the
    band emissivity is their mean, eps = sum_k,s B_k eps_h,k,s / (n_sides sum_k B_k), so that
    eps A is the sum over the sides of eps_s A (Kirchhoff per side, CONTRACTS §7)."""
    P = ts.n_parts
    rad = np.array([[band_radiance_w_m2_sr(a, b, t) for t in temps] for a, b, _ in bands])  # (K, P)
    eps_h = np.zeros((len(bands), P, 2))
    for k, (_, _, lam) in enumerate(bands):
        sides = ts.sides_at(lam)
        for p in range(P):
            for side in (0, 1) if ts.one_sided[p] else (0,):
                eps_h[k, p, side] = sides.hemispherical(p, side)
    n_sides = np.where(ts.one_sided, 2, 1)
    emitted = np.pi * rad[:, :, None] * eps_h
    band_eps = emitted.sum(axis=(0, 2)) / (np.pi * rad.sum(axis=0) * n_sides)
    area_mm2 = np.array([ts.part_area_mm2(p) for p in range(P)]) * n_sides
    return emitted, band_eps, area_mm2


def _stratum_rays(per_part: int, share: float) -> int:
    """Rays of a stratum with ``share`` of its part's emitted power: in proportion, at least 2 (0 without a share)."""
    if not share > 0:
        return 0
    return max(2, round(per_part * share))


def _warn_truncated(cut, names) -> None:
    """A TruncationWarning naming the part whose emission the event cap cut most, above 1 %."""
    from straylight.thermal import walk as walk_module  # MAX_EVENTS read now (tests lower it)

    MAX_EVENTS = walk_module.MAX_EVENTS
    k = int(np.argmax(cut)) if len(cut) else 0
    if len(cut) and cut[k] > TRUNCATION_WARN_FRACTION:
        warnings.warn(f"the event cap ({MAX_EVENTS} events: a closed mirror cavity) stopped {cut[k]:.1%} of the "
                      f"power {names[k]!r} emits, booked to no part (exchange_details.json 'truncated'); the "
                      f"row's D_ij are low by that much: give the cavity an absorbing or escaping part",
                      TruncationWarning, stacklevel=3)


def _emit_batch(ts, sides, i, sampler, draws, side: int = 0):
    """Per-ray absorbed fractions of a batch of whole chunks from part i's ``side`` (0 front, 1 back;
    ``draws``: straylight.rng.BatchDraws): sums (P + 2,) and sums of squares (entry P is the escaped
    fraction, P + 1 what the event cap cut)."""
    P = ts.n_parts
    n = draws.n_rays
    o, nrm, d = emission_rays(sampler, sides.eps[i, side], draws.all(3), draws, np.arange(n), back=side == 1)
    book = np.zeros((P + 2) * n)  # (part, escaped or cut at the event cap, ray)

    def ended(ev):  # escaped (booked to P), or all of it to the absorber or detector hit
        part = np.where(ev.alive, ev.hit.part, P)
        np.add.at(book, part[ev.ends] * n + ev.ray[ev.ends], ev.w[ev.ends])

    def removed(ev, w_next):  # what the interaction and roulette took; at the event cap, the rest is cut
        c = ev.cont
        if ev.capped:
            out = ev.carried
            np.add.at(book, ev.hit.part[c] * n + ev.ray[c], ev.w[c] - out)  # absorbed at this last hit
            np.add.at(book, (P + 1) * n + ev.ray[c], out)  # what the path still carried: cut, not absorbed
            return
        np.add.at(book, ev.hit.part[c] * n + ev.ray[c], ev.w[c] - w_next)

    walk(ts, sides, draws, o, nrm, d, np.ones(n), ended, removed, warn_cap=False)  # reported per part instead
    x = book.reshape(P + 2, n)
    return x.sum(axis=1), (x * x).sum(axis=1)
