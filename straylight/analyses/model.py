"""Parametric designs from the user's own CadQuery code: ``--model mydesign.py:build``.

``build(**params)`` returns the design's named parts, as

- a dict ``{name: shape}`` (CadQuery ``Workplane``, ``Shape``/``Solid``/``Face``/``Compound``), or
- a ``cadquery.Assembly`` (each child with a shape becomes a part named by its assembly name,
  placed by the composed locations), or
- a tuple ``(parts, scene)`` where ``scene`` is a scene dict (below) that depends on the parameters.

What CAD does not say (roles, materials, the source, the entrance) comes from a **scene dict**: the
tuple's second item, or the module-level ``SCENE`` dict. Its keys mirror the scene TOML (CONTRACTS
§6) with the parts keyed by name and no meshes::

    SCENE = {
        "material": {"black": {"components": [{"type": "lambertian", "rd": 0.05}]}},  # optional
        "parts": {"detector": {"role": "detector"},                # per part: role, material
                  "*": {"role": "surface", "material": "z302_sample_b"}},   # every other part
        "source": [{"type": "collimated_disk", "center_mm": [0, 0, 310], "normal": [0, 0, -1],
                    "direction": [0, 0, -1], "radius_mm": 51.0}],
        "analysis": {"entrance": {...}, "detector": "detector"},   # optional (CONTRACTS §6.3)
        "tolerance_mm": 0.05,                                      # optional chord tolerance
    }

Each design is tessellated and written as a scene folder (meshes + scene.toml with the source and
``[analysis]``), so every command runs on it afterwards; the sweep traces it like any scene file.
Example: ``examples/parametric_baffle.py``.
"""
from __future__ import annotations

import importlib.util
import inspect
import re
import sys
from pathlib import Path

import numpy as np

from atomicio.digest import file_sha256
from straylight.analyses.grid import GridPoint, open_checkpoint, point_seed, run_grid
from straylight.analyses.pst import detector_area, detector_name, pst_job, pst_options
from straylight.analyses.scene_setup import scene_setup
from straylight.analyses.sweep import grid_points, sweep_result
from straylight.execution import Execution

PART_KEYS = ("role", "material")
SCENE_KEYS = ("material", "parts", "source", "analysis", "tolerance_mm")


class ModelError(ValueError):
    """A model file or its result that cannot become a scene; the message names the file."""


def load_model(spec: str):
    """``"path/to/file.py:function"`` -> (function, module)."""
    if ":" not in spec:
        raise ModelError(f"--model must be FILE.py:FUNCTION, got {spec!r}")
    path_s, func = spec.rsplit(":", 1)
    path = Path(path_s)
    if not path.is_file():
        raise ModelError(f"{path}: model file not found")
    if path.suffix != ".py":  # /etc/passwd:build gave "'NoneType' object has no attribute 'loader'"
        raise ModelError(f"{path}: a model is a Python file ending in .py (--model FILE.py:FUNCTION)")
    name = f"_straylight_model_{abs(hash(str(path.resolve())))}"
    mod_spec = importlib.util.spec_from_file_location(name, path)
    if mod_spec is None or mod_spec.loader is None:
        raise ModelError(f"{path}: cannot be imported as a Python module (--model FILE.py:FUNCTION)")
    module = importlib.util.module_from_spec(mod_spec)
    sys.modules[name] = module
    try:
        mod_spec.loader.exec_module(module)
    except SystemExit as exc:  # sys.exit() in the model ended straylight with exit 0 and no report
        raise ModelError(f"{path}: importing the model called sys.exit({exc.code!r}); a model must not exit") from None
    except Exception as exc:  # noqa: BLE001 - the user's code: name the file and the error
        raise ModelError(f"{path}: importing the model failed: {type(exc).__name__}: {exc}") from exc
    fn = getattr(module, func, None)
    if not callable(fn):
        raise ModelError(f"{path}: no function {func!r}")
    return fn, module


def check_parameter(fn, parameter: str, where: str):
    """The model's ``build`` must accept ``parameter`` (a named parameter or ``**kwargs``)."""
    sig = inspect.signature(fn)
    if parameter in sig.parameters or any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values()):
        return
    names = [p for p in sig.parameters]
    raise ModelError(f"{where}: {fn.__name__}() has no parameter {parameter!r}; its parameters: "
                     f"{', '.join(names) or 'none'}")


def _shape_of(obj):
    if hasattr(obj, "vals") and hasattr(obj, "val"):  # a Workplane
        vals = [v for v in obj.vals() if hasattr(v, "wrapped")]
        if not vals:
            raise ModelError("a Workplane part holds no shape")
        if len(vals) == 1:
            return vals[0]
        import cadquery as cq

        return cq.Compound.makeCompound(vals)
    if hasattr(obj, "wrapped"):
        return obj
    raise ModelError(f"a part must be a CadQuery Workplane or Shape, got {type(obj).__name__}")


def _assembly_parts(assy) -> dict:
    out = {}

    def walk(a, loc):
        here = loc * a.loc if loc is not None else a.loc
        if a.obj is not None:
            out[a.name] = _shape_of(a.obj).moved(here)
        for child in a.children:
            walk(child, here)

    walk(assy, None)
    return out


def model_parts(result, module_scene, where: str):
    """The model's return value -> ({name: shape}, scene dict)."""
    scene = module_scene
    if isinstance(result, tuple):
        if len(result) != 2 or not isinstance(result[1], dict):
            raise ModelError(f"{where}: build() returned a tuple; it must be (parts, scene dict)")
        result, scene = result
    if type(result).__name__ == "Assembly":
        parts = _assembly_parts(result)
    elif isinstance(result, dict):
        parts = {}
        for name, obj in result.items():
            try:
                parts[str(name)] = _shape_of(obj)
            except ModelError as exc:
                raise ModelError(f"{where}: part {name!r}: {exc}") from None
    else:
        raise ModelError(f"{where}: build() must return a dict of named CadQuery parts, a cadquery.Assembly "
                         f"or (parts, scene dict), got {type(result).__name__}")
    if not parts:
        raise ModelError(f"{where}: build() returned no parts")
    if scene is None:
        raise ModelError(f"{where}: no scene settings: define SCENE = {{...}} in the model file or return "
                         "(parts, scene) from build() (roles, materials, source; docs/study.md)")
    return parts, scene


def write_design_scene(parts: dict, scene: dict, directory, where: str) -> Path:
    """Tessellate the parts and write DIR/scene.toml (+ meshes) from the scene dict."""
    from geometry.io import save_scene
    from geometry.mesh import Scene
    from geometry.tessellate import tessellate

    unknown = sorted(set(scene) - set(SCENE_KEYS))
    if unknown:
        raise ModelError(f"{where}: SCENE: unknown key(s) {', '.join(unknown)}; expected {', '.join(SCENE_KEYS)}")
    settings = scene.get("parts", {})
    if not isinstance(settings, dict):
        raise ModelError(f"{where}: SCENE['parts'] must be a dict part name -> {{role, material}}")
    missing = sorted(set(settings) - set(parts) - {"*"})
    if missing:
        raise ModelError(f"{where}: SCENE['parts'] names part(s) the model did not build: {', '.join(missing)}; "
                         f"built: {', '.join(parts)}")
    if not scene.get("source"):
        raise ModelError(f"{where}: SCENE needs a 'source' list (a collimated_disk for the analyses)")
    tol = float(scene.get("tolerance_mm", 0.05))
    default = settings.get("*", {})
    meshed = []
    for name, shape in parts.items():
        if not re.fullmatch(r"[A-Za-z0-9_.\-]+", name):
            raise ModelError(f"{where}: part name {name!r}: use letters, digits, _ . - only (it names a file)")
        entry = {**default, **settings.get(name, {})}
        bad = sorted(set(entry) - set(PART_KEYS))
        if bad:
            raise ModelError(f"{where}: part {name!r}: unknown key(s) {', '.join(bad)}; expected role, material")
        role = entry.get("role", "surface")
        material = entry.get("material") if role == "surface" else None
        if role == "surface" and material is None:
            raise ModelError(f"{where}: part {name!r} is a surface without a material (give one, or a '*' default)")
        meshed.append(tessellate(shape, name=name, tolerance_mm=tol, material=material, role=role))
    path = save_scene(Scene(tuple(meshed)), directory, materials=scene.get("material"),
                      sources=[dict(s) for s in scene["source"]])
    if scene.get("analysis"):
        import tomllib

        import tomli_w

        import atomicio

        doc = tomllib.loads(Path(path).read_text())
        doc["analysis"] = dict(scene["analysis"])
        atomicio.write_text(path, tomli_w.dumps(doc))
    return Path(path)


def _value(v: float):
    """Sweep values arrive as floats; integral ones go to build() as int (vane counts)."""
    return int(v) if float(v).is_integer() else float(v)


def design_scene(model: str, params: dict, directory) -> Path:
    """Build the model with ``params`` and write its scene folder; returns the scene.toml path."""
    fn, module = load_model(model)
    where = model.rsplit(":", 1)[0]
    for key in params:
        check_parameter(fn, key, where)
    try:
        result = fn(**params)
    except SystemExit as exc:
        raise ModelError(f"{where}: {fn.__name__}() called sys.exit({exc.code!r}); a model must return its parts") \
            from None
    except Exception as exc:  # noqa: BLE001 - the user's code
        shown = ", ".join(f"{k}={v!r}" for k, v in params.items())
        raise ModelError(f"{where}: {fn.__name__}({shown}) failed: {type(exc).__name__}: {exc}") from exc
    parts, scene = model_parts(result, getattr(module, "SCENE", None), where)
    return write_design_scene(parts, scene, directory, where)


def model_sweep(model: str, parameter: str, values, off_axis, out_dir, n_rays: int = 50_000, seed: int = 0,
                nee: bool = True, execution: Execution | None = None, precision=None, checkpoint_dir=None,
                resume: bool = False):
    """PST at ``off_axis`` (radians) of each design ``build(parameter=value)``.

    Each design's scene folder is ``out_dir/<parameter>=<value>/``; the (design, angle) points run on
    the grid runner (:func:`straylight.analyses.grid.run_grid`), point k = i * n_angles + j traced with
    the seed ``point_seed(point_seed(seed, k), 0)`` (the seed of a one-angle ``pst`` sweep seeded
    ``point_seed(seed, k)``: the numbers of the sweeps before the grid runner). ``execution``: where to
    run and whether to show progress; ``precision``: trace each point to a target relative error.
    ``checkpoint_dir``: each finished point is written there (:class:`straylight.checkpoints.PointStore`,
    with the model file's content in the fingerprint); ``resume`` reads back the points an interrupted
    run of the same sweep finished, and a design whose points are all done is not built again.
    """
    fn, _ = load_model(model)
    where = model.rsplit(":", 1)[0]
    check_parameter(fn, parameter, where)
    values = np.asarray(list(values), dtype=np.float64)
    if len(values) == 0:
        raise ModelError("the sweep needs at least one value")
    off_axis = np.atleast_1d(np.asarray(off_axis, dtype=np.float64))
    out_dir = Path(out_dir)
    opts = pst_options(nee)
    store = open_checkpoint(checkpoint_dir, {
        "sweep": "model_sweep", "model": model, "model_sha256": file_sha256(where),
        "parameter": parameter, "values": values, "off_axis": off_axis, "rays": int(n_rays), "seed": int(seed),
        "nee": bool(nee), "precision": None if precision is None else dict(precision.__dict__)}, resume)
    built: dict = {}

    def setup_of(i: int):
        if i not in built:  # built only when one of its points is still to trace
            v = values[i]
            setup = scene_setup(design_scene(model, {parameter: _value(v)}, out_dir / f"{parameter}={v:g}"))
            det = detector_name(setup.scene, setup.detector)
            built[i] = (setup, det, detector_area(setup, det).area_mm2)
        return built[i]

    def job(point: GridPoint):
        i, j = divmod(point.key, len(off_axis))
        setup, det, area = setup_of(i)
        return pst_job(setup, det, area, off_axis[j], 0.0, opts)

    points = grid_points(values, off_axis, seed, parameter, seed_of=lambda s, k: point_seed(point_seed(s, k), 0))
    runs = run_grid(points, job, execution, rays=int(n_rays), precision=precision, checkpoint=store,
                    desc=f"sweep {parameter}")
    return sweep_result(parameter, values, off_axis, runs, int(n_rays), int(seed), f"model {model}")
