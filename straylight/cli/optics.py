"""``straylight optics``: import (a lens file -> scene.toml + prescription.json) and info (docs/optics.md)."""
from __future__ import annotations

import sys


def _glass_pairs(items) -> dict:
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"--glass {item!r}: expected NAME=N (the glass's refractive index)")
        name, value = item.split("=", 1)
        try:
            n = float(value)
        except ValueError:
            raise ValueError(f"--glass {item!r}: {value!r} is not a number") from None
        if not n >= 1.0:
            raise ValueError(f"--glass {item!r}: index must be >= 1")
        out[name.strip()] = n
    return out


def _read(args):
    from straylight.optics.reader import read_prescription

    return read_prescription(args.lens, wavelength_nm=getattr(args, "wavelength_nm", None),
                             glass=_glass_pairs(getattr(args, "glass", None)), force=getattr(args, "force", False))


def run_import(args) -> int:
    from straylight.optics.output import write_outputs
    from straylight.optics.scene_build import build_scene

    if args.wavelength_nm is not None and not args.wavelength_nm > 0:
        raise ValueError(f"--wavelength-nm must be > 0, got {args.wavelength_nm:g}")
    if not -90 < args.field_deg < 90:
        raise ValueError(f"--field-deg must be in (-90, 90), got {args.field_deg:g}")
    p = _read(args)
    scene = build_scene(p, field_deg=args.field_deg, edge_material=args.edge_material, coating=args.coating)
    write_outputs(p, scene, args.out)
    for w in p.warnings:
        print(f"warning: {w}", file=sys.stderr)
    n_opt = sum(1 for s in p.surfaces if not s.dummy)
    import math

    first_order = (f"efl {p.efl_mm:.6g} mm, f/# {p.fno:.3g}" if math.isfinite(p.efl_mm) and math.isfinite(p.fno)
                   else "afocal (no efl, f/#)")
    print(f"{p.file}: {n_opt} optical surfaces, {first_order}, at {p.wavelength_nm:g} nm -> "
          f"{args.out}/scene.toml, {args.out}/prescription.json")
    return 0


def run_info(args) -> int:
    from straylight.optics.output import info_text

    print(info_text(_read(args)))
    return 0


def add_parser(subparsers):
    g = subparsers.add_parser("optics", help="lens-design files in: CODE V .seq and Zemax .zmx (import, info)",
                              description="straylight optics: the designer's lens file (CODE V .seq, Zemax .zmx "
                                          "in UTF-8 or UTF-16) as exact analytic surfaces; see docs/optics.md.")
    sub = g.add_subparsers(dest="optics_command", metavar="SUBCOMMAND", required=True)
    p = sub.add_parser("import", help="write DIR/scene.toml and DIR/prescription.json from a lens file",
                       description="Reads a lens file (recognised by content) and writes DIR/scene.toml (one exact "
                                   "part per optical surface, black lens edges and stop, the detector image and the "
                                   "collimated source pupil) and DIR/prescription.json (first-order data, surfaces).")
    p.add_argument("lens", help="lens file: CODE V .seq or Zemax .zmx")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--wavelength-nm", type=float, default=None,
                   help="wavelength of the indices and the source (default: the file's reference wavelength)")
    p.add_argument("--field-deg", type=float, default=0.0, help="field angle of the pupil source (meridional, y-z)")
    p.add_argument("--glass", nargs="+", default=(), metavar="NAME=N",
                   help="refractive index of a glass the catalogues lack")
    p.add_argument("--force", action="store_true",
                   help="import surfaces of unsupported types as their base sphere/conic (with a warning)")
    p.add_argument("--edge-material", default="z302_sample_b",
                   help="material of lens edges, flat rings, the stop and mirror backs (default z302_sample_b)")
    p.add_argument("--coating", default=None, metavar="NAME",
                   help="coating of every lens surface against air (a named design of docs/reference/material.md, "
                        "e.g. mgf2_quarter_wave, broadband_ar)")
    p.set_defaults(func=run_import)
    i = sub.add_parser("info", help="print the first-order data and the surface table (writes nothing)",
                       description="Prints a lens file's first-order data (paraxial) and its surface table in the "
                                   "frame and units of optics import, with warnings; writes nothing.")
    i.add_argument("lens", help="lens file: CODE V .seq or Zemax .zmx")
    i.add_argument("--wavelength-nm", type=float, default=None, help="wavelength (default: the file's reference)")
    i.add_argument("--glass", nargs="+", default=(), metavar="NAME=N", help="index of a glass the catalogues lack")
    i.add_argument("--force", action="store_true", help="show files with unsupported surface types too")
    i.set_defaults(func=run_info)
