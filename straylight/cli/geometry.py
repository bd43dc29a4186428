"""``straylight geometry``: build parametric parts to STEP + meshes + scene TOML; check a scene.

    straylight geometry build tube [--vanes N] [--vane-bevel-deg B] ... [--tolerance-mm T] -o DIR
    straylight geometry build reflectometer --theta-i-deg A --theta-r-deg B [--arm-mm L] ... -o DIR
    straylight geometry check SCENE.toml [--strict] [--json OUT.json]
    straylight geometry scene ASSEMBLY.step -o SCENE.toml [--detector NAME | --detector-disk X Y Z NX NY NZ R]
                              [--entrance-disk X Y Z NX NY NZ R] [--material M] [--tolerance-mm T]
"""
from __future__ import annotations

import dataclasses
import warnings

TUBE_ALIASES = {"vane_count": "--vanes"}


def _flag(name: str) -> str:
    return TUBE_ALIASES.get(name, "--" + name.replace("_", "-"))


def _add_dataclass_flags(parser, cls):
    for f in dataclasses.fields(cls):
        kind = {"int": int, "str": str}.get(str(f.type), float)
        extra = {"nargs": "+"} if "tuple" in str(f.type) else {}
        parser.add_argument(_flag(f.name), dest=f"param_{f.name}", type=kind, default=None,
                            metavar=f.name.split("_")[-1].upper() if kind is float else "VALUE",
                            help=f"{f.name} (default {f.default!r})", **extra)


def _params(args) -> dict:
    return {k[6:]: v for k, v in vars(args).items() if k.startswith("param_") and v is not None}


def _common(parser, tolerance_mm):
    parser.add_argument("-o", "--output", required=True, help="output directory")
    parser.add_argument("--tolerance-mm", type=float, default=tolerance_mm, help="chord tolerance (mm)")
    parser.add_argument("--angular-tolerance-deg", type=float, default=10.0, help="angular tolerance (deg)")
    parser.add_argument("--mesh-format", choices=("stl", "ply", "obj"), default="stl")
    parser.add_argument("--no-step", action="store_true", help="skip the STEP files")
    parser.add_argument("--json", metavar="PATH", help="write the reports as JSON")
    parser.add_argument("--force", action="store_true",
                        help="overwrite files in the output folder that straylight did not write or that were changed")


def add_parser(subparsers):
    from geometry.parts.reflectometer import ReflectometerParams
    from geometry.parts.tube import TubeParams

    geometry = subparsers.add_parser("geometry", help="build and check geometry")
    geometry.set_defaults(func=_usage(geometry))
    group = geometry.add_subparsers(dest="what", metavar="ACTION")
    build_parser = group.add_parser("build", help="build parts, write STEP + meshes + scene TOML")
    build_parser.set_defaults(func=_usage(build_parser))
    build = build_parser.add_subparsers(dest="model", metavar="MODEL")
    tube = build.add_parser("tube", help="baffled tube (defaults: the BENCHMARK.md tube)")
    _add_dataclass_flags(tube, TubeParams)
    tube.add_argument("--material", default="benchmark_black", help="material name of every surface")
    _common(tube, 0.05)
    tube.set_defaults(func=_build_tube)
    rig = build.add_parser("reflectometer", help="the seed paper's reflectometer at one set-point")
    rig.add_argument("--theta-i-deg", type=float, required=True)
    rig.add_argument("--theta-r-deg", type=float, required=True)
    rig.add_argument("--phi-r-deg", type=float, default=0.0, help="0 (specular half-plane) or 180")
    _add_dataclass_flags(rig, ReflectometerParams)
    rig.add_argument("--sample-material", default=None)
    rig.add_argument("--black-material", default=None)
    _common(rig, 0.01)
    rig.set_defaults(func=_build_reflectometer)
    check = group.add_parser("check", help="check a scene's meshes (watertight, winding, overlaps)",
                             description="Check every part's mesh and every overlap of two solids (its volume and "
                                         "depth). Exit 1 where an overlap would change a trace (a detector or a "
                                         "dielectric part in it, or deeper than the chord tolerance); small "
                                         "interferences of opaque parts are listed and exit 0.")
    check.add_argument("scene", metavar="SCENE", help="scene TOML, or a STEP/IGES/STL/OBJ/PLY file as a one-file scene")
    check.add_argument("--strict", action="store_true",
                       help="exit 1 if any check fails (overlaps that change a trace always exit 1)")
    check.add_argument("--json", metavar="PATH")
    check.set_defaults(func=_check)
    scene = group.add_parser("scene", help="write a scene file for your own STEP/IGES assembly (one part per solid)")
    scene.add_argument("cad", metavar="ASSEMBLY.step", help="STEP or IGES file from any CAD tool")
    scene.add_argument("-o", "--output", required=True, metavar="SCENE.toml")
    which = scene.add_mutually_exclusive_group()
    which.add_argument("--detector", default=None, metavar="NAME",
                       help="solid that is the detector (default: the solid named 'detector', if any)")
    disk = ("X", "Y", "Z", "NX", "NY", "NZ", "R")
    which.add_argument("--detector-disk", type=float, nargs=7, default=None, metavar=disk,
                       help="add a detector that is the exact disk of centre X Y Z (mm), normal NX NY NZ (its "
                            "sensitive side) and radius R (mm) (CONTRACTS 6.4): CAD rarely holds a detector solid")
    scene.add_argument("--entrance-disk", type=float, nargs=7, default=None, metavar=disk,
                       help="the entrance aperture for the analyses ([analysis] entrance): centre, normal "
                            "(outward), radius")
    scene.add_argument("--material", default="z302_sample_b", help="material of every other solid")
    scene.add_argument("--tolerance-mm", type=float, default=0.05, help="chord tolerance (mm)")
    scene.add_argument("--force", action="store_true", help="overwrite SCENE.toml even if it was edited by hand")
    scene.add_argument("--axis", type=float, nargs=3, default=(0.0, 0.0, 1.0), metavar=("X", "Y", "Z"),
                       help="the instrument looks toward +axis; the beam travels along -axis (default 0 0 1)")
    scene.set_defaults(func=_scene)


def _usage(parser):
    def show(args) -> int:
        parser.print_help()
        return 2

    return show


def _build_outputs(args, shape_parts) -> list:
    """The files ``geometry build`` writes in its folder (geometry.io.export_build)."""
    names = [f"{name}.{args.mesh_format}" for name in shape_parts] + ["scene.toml"]
    if not args.no_step:
        names += [f"{name}.step" for name in shape_parts] + ["assembly.step"]
    return names


def _guard_build(args, shape_parts) -> None:
    """Before tessellating: the folder is writable and no file the build writes was written or
    changed by the user (atomicio.guard), unless --force."""
    from atomicio.guard import check_output_dir, check_overwrite

    check_output_dir(args.output, "-o folder")
    check_overwrite(args.output, names=_build_outputs(args, shape_parts), force=args.force)


def _finish(args, shape_parts, scene, tables: dict | None = None) -> int:
    from geometry.checks import check_scene
    from geometry.io import export_build
    from geometry.tessellate import format_reports, scene_report

    path = export_build(shape_parts, scene, args.output, mesh_format=args.mesh_format, step=not args.no_step)
    if tables:
        from straylight.analyses.scene_setup import add_scene_tables

        add_scene_tables(path, tables)
    print(format_reports(scene_report(scene)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the problems are printed in the table below
        checks = check_scene(scene)
    print(checks.format())
    from atomicio.guard import record_outputs

    record_outputs(args.output, names=_build_outputs(args, shape_parts))
    print(f"scene: {path}")
    if args.json:
        import atomicio

        atomicio.write_json(args.json, {"scene": str(path), "tessellation": [r.as_dict() for r in scene_report(scene)],
                                        "checks": checks.as_dict()}, final_newline=False)
    return 0 if checks.ok else 1


def _build_tube(args) -> int:
    from geometry.parts.tube import TubeParams, build_tube
    from geometry.tessellate import tessellate_parts

    params = TubeParams(**_params(args))
    shape_parts = build_tube(params)
    _guard_build(args, shape_parts)
    scene = tessellate_parts(shape_parts, tolerance_mm=args.tolerance_mm,
                             angular_tolerance_deg=args.angular_tolerance_deg, material=args.material)
    return _finish(args, shape_parts, scene, _tube_tables(params, args.material))


def _tube_tables(params, material: str) -> dict:
    """The tube scene's PST beam as its ``[[source]]``, its ``[analysis]`` table, and the BENCHMARK.md
    coating (Lambertian, rho = 0.05) inline when the default name is used, so every analysis runs on
    the written scene file as on ``--builtin tube``."""
    from geometry.scenes import BENCHMARK_MATERIAL
    from straylight.analyses.builtin import tube_beam_and_entrance
    from straylight.analyses.scene_setup import scene_tables

    source, analysis = scene_tables(*tube_beam_and_entrance(params), "detector")
    tables = {"source": [source], "analysis": analysis}
    if material == BENCHMARK_MATERIAL:
        tables["material"] = {BENCHMARK_MATERIAL: {"components": [{"type": "lambertian", "rd": 0.05}]}}
    return tables


def _build_reflectometer(args) -> int:
    from geometry.parts.reflectometer import ReflectometerParams, build_reflectometer
    from geometry.tessellate import tessellate_parts

    shape_parts = build_reflectometer(args.theta_i_deg, args.theta_r_deg, args.phi_r_deg,
                                      ReflectometerParams(**_params(args)))
    _guard_build(args, shape_parts)
    scene = tessellate_parts(shape_parts, tolerance_mm=args.tolerance_mm,
                             angular_tolerance_deg=args.angular_tolerance_deg, material=args.black_material,
                             materials={"sample": args.sample_material})
    return _finish(args, shape_parts, scene)


def _check(args) -> int:
    import sys

    from geometry.checks import check_scene

    scene, transparent, note = _scene_to_check(args.scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        checks = check_scene(scene, transparent=transparent)
    print(checks.format())
    if note:
        print(note)
    if args.json:
        import atomicio

        atomicio.write_json(args.json, checks.as_dict(), final_newline=False)
    changing = checks.trace_changing_overlaps
    if changing:  # overlaps a ray would notice make numbers that mean nothing: never exit 0
        first = changing[0]
        print(f"straylight: geometry check: {len(changing)} overlap(s) change the trace (first: {first.a} / "
              f"{first.b}, {first.volume_mm3:.3g} mm^3, depth {first.depth_mm:.3g} mm: {first.why}); move or trim "
              f"the parts", file=sys.stderr)
        return 1
    return 1 if (args.strict and not checks.ok) else 0


def _scene_to_check(path):
    """(geometry Scene, names of its transparent parts, a note or None) of a scene TOML or a CAD/mesh file.

    Transparent: a part whose material (or back material) transmits (a ``dielectric`` component); that needs
    the materials resolved, which a scene whose materials do not load cannot give (then: none, and a note)."""
    from pathlib import Path

    from geometry.io import CAD_SUFFIXES, MESH_SUFFIXES, load_scene_or_file

    if Path(path).suffix.lower() in CAD_SUFFIXES + MESH_SUFFIXES:
        return load_scene_or_file(path), frozenset(), None
    from geometry.mesh import GeometryError
    from straylight.scene import load_scene

    try:
        rs = load_scene(path, sources=False, check_watertight=False)  # the check reports watertightness itself
    except GeometryError:
        raise
    except Exception as exc:  # noqa: BLE001 - materials or sources that do not load: check the meshes all the same
        from geometry.io import load_scene as load_geometry

        return load_geometry(path), frozenset(), (f"note: materials not resolved ({str(exc).splitlines()[0]}); "
                                                  f"overlaps with glass parts are not told apart")
    from materials.flags import ComponentFlags, flags_of

    def transmits(name) -> bool:
        model = rs.materials.get(name) if name is not None else None
        return model is not None and bool(flags_of(model) & ComponentFlags.DELTA_TRANSMISSION)

    clear = {p.name for p in rs.scene.parts if transmits(p.material) or transmits(getattr(p, "back_material", None))}
    return rs.scene, frozenset(clear), None


def _scene(args) -> int:
    import tomllib
    from pathlib import Path

    from atomicio.guard import check_output_file, check_overwrite, record_outputs
    from geometry.cad_scene import detector_of, write_cad_scene

    out = check_output_file(args.output, "-o scene file")
    check_overwrite(out.parent, names=[out.name], force=args.force)

    path, parts = write_cad_scene(args.cad, args.output, detector=args.detector, material=args.material,
                                  tolerance_mm=args.tolerance_mm, axis=args.axis, detector_disk=args.detector_disk,
                                  entrance_disk=args.entrance_disk)
    detector = detector_of(tomllib.loads(path.read_text()))
    width = max([len(p.name) for p in parts] + [len("detector")])
    for p in parts:
        role = "detector" if p.name == detector else p.role
        print(f"{p.name:<{width}} {role:<8} {p.n_triangles:>9d} triangles  "
              f"chord error {p.meta['tessellation'].max_chord_error_mm:.3g} mm")
    if args.detector_disk is not None:
        x, y, z, *_, r = args.detector_disk
        print(f"{'detector':<{width}} {'detector':<8} exact disk r = {r:g} mm at ({x:g}, {y:g}, {z:g})")
    print(f"{'total':<{width}} {'':<8} {sum(p.n_triangles for p in parts):>9d} triangles in {len(parts)} parts")
    record_outputs(Path(path).parent, names=[Path(path).name])
    print(f"scene: {path}")
    if detector is None:
        print("no detector yet: the analyses need one; write the scene again with --detector-disk X Y Z NX NY NZ R "
              "(or --detector SOLID), or add a detector part to it (docs/reference/scene.md)")
    return 0
