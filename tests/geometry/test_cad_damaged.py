"""A damaged STEP file never takes the process down : read in a child process, every
damage gets a scene or a one-line error naming the file. The base file is tests/data/cad/gmsh_parts.step;
deleting one ``#n = VECTOR(...)`` line made OpenCascade's transfer crash with SIGSEGV in-process."""
import random
import re
from pathlib import Path

import pytest

from geometry.mesh import GeometryError

BASE = Path(__file__).resolve().parents[1] / "data" / "cad" / "gmsh_parts.step"


def _variants():
    text = BASE.read_text()
    lines = text.splitlines(keepends=True)
    data = BASE.read_bytes()
    vectors = [i for i, line in enumerate(lines) if re.match(r"#\d+\s*=\s*VECTOR\(", line)]
    out = {}
    for k in (0, len(vectors) // 2, len(vectors) - 1):  # delete one VECTOR line (the crash this guards against)
        out[f"no-vector-{k}"] = "".join(lines[:vectors[k]] + lines[vectors[k] + 1:]).encode()
    for fraction in (0.1, 0.5, 0.97):  # truncated
        out[f"truncated-{fraction}"] = data[:int(len(data) * fraction)]
    rng = random.Random(7)
    for k in range(3):  # flipped bytes in the data section
        damaged = bytearray(data)
        for _ in range(20):
            i = rng.randrange(len(data) // 10, len(data))
            damaged[i] ^= 0xFF
        out[f"flipped-{k}"] = bytes(damaged)
    refs = re.findall(r"#(\d+)", text)
    out["dangling-ref"] = re.sub(rf"#{refs[len(refs) // 3]}\b(?!\s*=)", "#9999999", text, count=3).encode()
    out["empty"] = b""
    out["binary"] = bytes(range(256)) * 8
    return out


VARIANTS = _variants()


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_damaged_step_gives_a_scene_or_one_line_error(name, tmp_path, monkeypatch):
    from geometry.cad_child import ENV_ISOLATE
    from geometry.io import tessellate_cad

    monkeypatch.setenv(ENV_ISOLATE, "on")
    path = tmp_path / f"{name}.step"
    path.write_bytes(VARIANTS[name])
    try:
        items = tessellate_cad(path, tolerance_mm=0.2)
    except GeometryError as exc:
        message = str(exc)
        assert "\n" not in message and str(path) in message, message
    else:
        assert items and all(part.n_triangles > 0 for *_, part in items)


def test_a_crash_in_the_reader_is_reported_as_such(tmp_path, monkeypatch):
    """The reproduction: in-process this SIGSEGVs; isolated it is a one-line error."""
    from geometry.cad_child import ENV_ISOLATE
    from geometry.io import tessellate_cad

    monkeypatch.setenv(ENV_ISOLATE, "on")
    path = tmp_path / "crash.step"
    path.write_bytes(VARIANTS["no-vector-0"])
    with pytest.raises(GeometryError, match=r"crash\.step: OpenCascade crashed reading the file \(SIGSEGV\)"):
        tessellate_cad(path, tolerance_mm=0.2)


def test_reader_time_limit_stops_the_child(tmp_path, monkeypatch):
    from geometry.cad_child import ENV_ISOLATE, ENV_TIMEOUT
    from geometry.io import tessellate_cad

    monkeypatch.setenv(ENV_ISOLATE, "on")
    monkeypatch.setenv(ENV_TIMEOUT, "0.05")
    with pytest.raises(GeometryError, match=r"gmsh_parts\.step: reading and tessellating took more than 0\.05 s"):
        tessellate_cad(BASE, tolerance_mm=0.2)
