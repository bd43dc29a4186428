"""Every file the project writes goes through atomicio ("every result writer through
atomicio"): no module of materials/, geometry/, straylight/ or rig/ opens a file for writing,
dumps JSON into a file, writes through ``Path.write_text``, replaces files by hand, or serialises
JSON itself for a writer (``json.dumps`` handed to ``write_text``: that is :func:`atomicio.write_json`).

Walks every module with ``ast``; the patterns and the few exceptions are listed here, each with its
reason. A new hand-written writer fails with the file and line.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("materials", "geometry", "straylight", "rig")
WRITER_CALLS = {"write_text", "write_bytes", "append_text", "write"}
FORBIDDEN_CALLS = {
    ("json", "dump"): "json.dump into a file: use atomicio.write_json",
    ("os", "replace"): "a hand-made atomic replace: use atomicio",
    ("os", "rename"): "a hand-made atomic replace: use atomicio",
    ("shutil", "move"): "a hand-made replace: use atomicio",
    ("np", "savetxt"): "np.savetxt: build the text and use atomicio.write_text",
    ("numpy", "savetxt"): "np.savetxt: build the text and use atomicio.write_text",
}
#: (file, what) -> why it may stay. Keep this short.
ALLOWED = {
    ("geometry/cad_cache.py", "np.savez"): "into an in-memory buffer, whose bytes go to atomicio.write_bytes",
    ("geometry/io.py", ".export(str(...))"): "CadQuery's STEP exporter writes into a scratch folder "
                                             "(_write_through_scratch); the bytes go to atomicio.write_bytes",
}


def _dotted(node) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return "?"


def _mode(call: ast.Call) -> str | None:
    """The constant mode string of an ``open(...)`` / ``x.open(...)`` call, or None."""
    args = call.args[1:2] if isinstance(call.func, ast.Name) else call.args[0:1]
    for kw in call.keywords:
        if kw.arg == "mode":
            args = [kw.value]
    if args and isinstance(args[0], ast.Constant) and isinstance(args[0].value, str):
        return args[0].value
    return None


def problems(path: Path, root: Path = ROOT) -> list[str]:
    rel = path.relative_to(root).as_posix()
    tree = ast.parse(path.read_text(), filename=rel)
    out = []

    def bad(node, what, why):
        if (rel, what) not in ALLOWED:
            out.append(f"{rel}:{node.lineno}: {what}: {why}")

    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _dotted(node.func)
        head, _, attr = name.rpartition(".")
        if (head, attr) in FORBIDDEN_CALLS:
            bad(node, name, FORBIDDEN_CALLS[(head, attr)])
        elif name in ("np.save", "np.savez", "np.savez_compressed", "numpy.save", "numpy.savez"):
            bad(node, "np.savez" if "savez" in name else "np.save", "writes a file by itself: use atomicio.write_bytes")
        elif attr in ("to_csv", "tofile", "savefig") and head not in ("", "atomicio"):
            bad(node, f".{attr}", "writes a file by itself: use atomicio (write_text, write_bytes, write_figure)")
        elif name == "open" or (attr == "open" and head not in ("atomicio", "os", "tarfile", "zipfile")):
            mode = _mode(node)
            if mode is not None and set(mode) & set("wax+"):
                bad(node, f"open(..., {mode!r})", "a file opened for writing: use atomicio")
        elif attr == "export" and any(isinstance(a, ast.Call) and _dotted(a.func) == "str" for a in node.args):
            bad(node, ".export(str(...))", "a library exporter writing a file name: write through atomicio")
        elif attr in ("write_text", "write_bytes") and head not in ("", "atomicio"):
            bad(node, f"{head}.{attr}", "Path.write_* is not atomic: use atomicio.write_text / write_bytes")
        elif name == "os.open":
            flags = {_dotted(n) for n in ast.walk(node) if isinstance(n, ast.Attribute)}
            if flags & {"os.O_WRONLY", "os.O_RDWR", "os.O_CREAT"}:
                bad(node, "os.open(O_WRONLY/O_CREAT)", "a file opened for writing: use atomicio")
        if attr in WRITER_CALLS or name in WRITER_CALLS:
            for arg in [*node.args, *(kw.value for kw in node.keywords)]:
                if any(isinstance(n, ast.Call) and _dotted(n.func) == "json.dumps" for n in ast.walk(arg)):
                    bad(node, f"{name}(json.dumps(...))", "JSON serialised by hand for a writer: use atomicio.write_json")
    return out


def test_no_module_writes_result_files_by_hand():
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            found += problems(path)
    assert not found, "\n".join(found)


def test_the_check_finds_each_pattern(tmp_path):
    """Each pattern of a hand-written writer is caught (so the test above can fail)."""
    src = (
        "import json, os\n"
        "from pathlib import Path\n"
        "import numpy as np\n"
        "def f(p, d, fig):\n"
        "    json.dump(d, open(p, 'w'))\n"               # 5: json.dump, 5: open w
        "    Path(p).write_text(json.dumps(d))\n"        # 6: Path.write_text (+ json.dumps in a writer)
        "    atomicio.write_text(p, json.dumps(d))\n"    # 7: json.dumps handed to a writer
        "    os.replace(p + '.tmp', p)\n"                # 8
        "    np.savetxt(p, d)\n"                         # 9
        "    fig.savefig(p)\n"                           # 10
        "    with Path(p).open('a') as fh: fh.write('x')\n"  # 11
        "    mesh.export(str(p), file_type='stl')\n"    # 12
        "    atomicio.write_json(p, d)\n"                # fine
        "    open(p).read()\n"                           # fine: reading
    )
    (tmp_path / "m.py").write_text(src)
    found = problems(tmp_path / "m.py", root=tmp_path)
    assert sorted(int(x.split(":")[1]) for x in found) == [5, 5, 6, 6, 7, 8, 9, 10, 11, 12], found
