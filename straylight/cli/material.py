"""``straylight material``: eval (CONTRACTS §4.2), fit, show, z307, import and export (§5.2).

Thin layer: parse, convert degrees to radians, call the materials library, write JSON.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

import atomicio


def _models():
    # registering every component type the library ships, before any material file is read
    import materials.kcorrelation  # noqa: F401
    import materials.lambertian  # noqa: F401
    import materials.microfacet  # noqa: F401
    import materials.bsdf_table  # noqa: F401


def _angle(name, value, lo=-90.0, hi=90.0):
    if not (lo <= value <= hi):
        raise ValueError(f"{name} = {value:g} is outside [{lo:g}, {hi:g}]")
    return value


def _progress(total, desc):
    from straylight.progress import progress_bar

    return progress_bar(total=total, desc=desc)


def _parse_pairs(items, option, bounds=False):
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"{option} {item!r}: expected NAME=VALUE" + (" with VALUE = LO:HI" if bounds else ""))
        name, value = item.split("=", 1)
        try:
            out[name.strip()] = tuple(float(v) for v in value.split(":")) if bounds else float(value)
        except ValueError:
            raise ValueError(f"{option} {item!r}: not a number") from None
        if bounds and len(out[name.strip()]) != 2:
            raise ValueError(f"{option} {item!r}: expected NAME=LO:HI")
    return out


# ---------------------------------------------------------------------- eval
def cmd_eval(args) -> int:
    _models()
    from materials.base import brdf_angles
    from materials.material import load_material

    material = load_material(args.model)
    theta_i_deg = _angle("--theta-i-deg", args.theta_i_deg, 0.0, 90.0)
    theta_r_deg = np.array([_angle("--theta-r-deg", v) for v in args.theta_r_deg])
    phi = np.array(args.phi_r_deg, float)
    if phi.size not in (1, theta_r_deg.size):
        raise ValueError(f"--phi-r-deg: give one value or one per --theta-r-deg ({theta_r_deg.size})")
    phi_r = np.radians(phi) + np.where(theta_r_deg < 0, np.pi, 0.0)  # negative theta_r: mirror side
    model = material
    rotation = getattr(args, "rotation_deg", None)
    if rotation is not None:  # an anisotropic table seen at this sample rotation (materials.bsdf_table)
        from materials.bsdf_table import rotated

        model = rotated(material, rotation)
    brdf = brdf_angles(model, np.radians(theta_i_deg), np.radians(np.abs(theta_r_deg)), phi_r,
                       args.polarization)
    if rotation is None:
        dhr = float(material.albedo(np.radians(theta_i_deg), args.polarization))
    else:
        from materials.albedo import directional_hemispherical_reflectance

        dhr = float(directional_hemispherical_reflectance(model, np.radians(theta_i_deg), args.polarization))
    smooth = material.smooth_coefficients(np.cos(np.radians([theta_i_deg]))) \
        if getattr(material, "smooth", None) is not None else None
    if smooth is not None:  # the specular part (delta lobe, not in brdf_per_sr) belongs to the dhr too
        dhr += float(smooth.reflectance(args.polarization)[0])
    out = {"material": material.name, "theta_i_deg": theta_i_deg, "theta_r_deg": theta_r_deg.tolist(),
           "phi_r_deg": np.broadcast_to(phi, theta_r_deg.shape).tolist(), "polarization": args.polarization,
           "brdf_per_sr": brdf.tolist(), "dhr": dhr}
    if smooth is not None:
        out["specular_reflectance"] = float(smooth.reflectance(args.polarization)[0])
        out["transmittance"] = float(smooth.transmittance(args.polarization)[0])
    for t, f in zip(theta_r_deg, brdf):
        print(f"theta_r = {t:8.3f} deg  BRDF = {f:.6g} 1/sr")
    print(f"dhr(theta_i = {theta_i_deg:g} deg, {args.polarization}) = {dhr:.6g}")
    if rotation is not None:
        out["rotation_deg"] = rotation
    if args.json:
        atomicio.write_json(args.json, out)
    return 0


# ---------------------------------------------------------------------- import / export (CONTRACTS 5.2)
def cmd_import(args) -> int:
    _models()
    from materials.bsdf_files import import_file
    from materials.material import save_material

    material, report = import_file(args.file, name=args.name)
    save_material(args.output, material, check_energy=False)  # import_file checked every rotation and node
    what = "BTDF" if report["scatter"] == "btdf" else "BRDF"
    rot = report["rotation_deg"]
    print(f"{args.file}: {report['format']} tabulated {what}, symmetry {report['symmetry']}, "
          f"{len(report['theta_i_deg'])} incidences ({', '.join(f'{t:g}' for t in report['theta_i_deg'])} deg)"
          + (f", {len(rot)} sample rotations" if len(rot) > 1 else ""))
    for note in report["notes"]:
        print(f"note: {note}")
    label = "DHT" if report["scatter"] == "btdf" else "DHR"
    tis = report["tis_in_file"]
    nt = len(report["theta_i_deg"])
    for r, row in enumerate(report["dhr"][:1] if len(report["dhr"]) > 4 else report["dhr"]):
        for j, (t, v) in enumerate(zip(report["theta_i_deg"], row)):
            line = f"  theta_i = {t:5.1f} deg: {label} {v:.5f}"
            if tis and len(tis) > r * nt + j and tis[r * nt + j] is not None:
                line += f"   (file's TIS line: {tis[r * nt + j]:g}, kept as reported, not used)"
            print(line + (f"  [rotation {rot[r]:g} deg]" if len(rot) > 1 else ""))
    print(f"wrote {args.output}")
    if args.json:
        atomicio.write_json(args.json, report, allow_nan=True)
    return 0


def cmd_export(args) -> int:
    _models()
    from materials.bsdf_files import _tables, export_fred, export_zemax
    from materials.material import load_material

    material = load_material(args.model)
    if material.smooth is not None:
        print(f"note: {material.name}: its {material.smooth.type_name} (delta) component is not a BSDF table "
              "and is not written; only the scatter lobes are", file=sys.stderr)
    if material.composite is None:
        raise ValueError(f"{args.model}: the material has no scatter lobes to export")
    if args.format == "zemax":
        text = export_zemax(material, aoi_deg=args.aoi_deg, radial_deg=args.radial_deg)
    else:
        if any(t.anisotropic for t in _tables(material)):
            print("note: FRED's tabulated BSDF is isotropic: the table is written at sample rotation 0",
                  file=sys.stderr)
        text = export_fred(material, aoi_deg=args.aoi_deg)
    atomicio.write_text(args.output, text)
    print(f"wrote {args.output} ({args.format})")
    return 0


# ---------------------------------------------------------------------- fit
def cmd_fit(args) -> int:
    _models()
    from materials.fit import fit, format_fit_report
    from materials.material import save_material
    from materials.scan import read_scan

    from materials.bsdf_files import detect, read_text, scan_from_file

    if detect(read_text(args.scan)) in ("zemax", "fred"):  # a lab's tabulated BSDF as the measurement
        scan = scan_from_file(args.scan, args.wavelength_nm)
        print(f"{args.scan}: {len(scan.brdf_per_sr)} in-plane nodes at "
              f"{', '.join(f'{t:g}' for t in np.unique(scan.theta_i_deg))} deg, {scan.wavelength_nm[0]:g} nm")
    else:
        scan = read_scan(args.scan)
    with _progress(args.starts, "fit starts") as bar:
        result = fit(scan, args.model, fixed=_parse_pairs(args.fix, "--fix"),
                     bounds=_parse_pairs(args.bound, "--bound", bounds=True), n_starts=args.starts,
                     seed=args.seed, progress=bar.update)
    print(format_fit_report(result))
    rms = ", ".join(f"{t:g} deg {p}: {v:.3f}" for (t, p), v in result.rms_log10.items())
    provenance = (f"fit of {result.model} to {Path(args.scan).name} (sample: {scan.metadata.get('sample', '?')}); "
                  f"rms log10 per incidence angle: {rms}; chi2/dof {result.chi2_reduced:.3g}")
    material = result.material(args.name or Path(args.output).stem, provenance=provenance)
    save_material(args.output, material)
    print(f"wrote {args.output}")
    if args.plot:
        from materials.plots import plot_fit

        print(f"wrote {plot_fit(scan, result, args.plot)}")
    if args.json:
        atomicio.write_json(args.json, result.to_json())
    return 0


# ---------------------------------------------------------------------- show
def cmd_show(args) -> int:
    _models()
    from materials.material import load_material

    material = load_material(args.model)
    print(json.dumps(material.to_dict(), indent=2))
    theta = np.array(args.theta_i_deg, float)
    rho = {p: material.albedo(np.radians(theta), p) for p in ("s", "p", "u")}
    print("\ndirectional-hemispherical reflectance rho(theta_i):\n  theta_i_deg         s         p         u")
    for k, t in enumerate(theta):
        print(f"  {t:11.1f} {rho['s'][k]:9.5f} {rho['p'][k]:9.5f} {rho['u'][k]:9.5f}")
    if args.plot:
        from materials.plots import plot_material

        print(f"wrote {plot_material(material, args.plot)}")
    if args.json:
        atomicio.write_json(args.json, {"material": material.to_dict(), "theta_i_deg": theta.tolist(),
                                        "rho": {p: v.tolist() for p, v in rho.items()}})
    return 0


# ---------------------------------------------------------------------- z307
def cmd_z307(args) -> int:
    from materials.fit import format_fit_report
    from materials.material import save_material
    from materials.z307 import Z307_PRESET_MODEL, fit_z307, read_z307

    models = args.compare or [args.model or Z307_PRESET_MODEL]
    rows, materials = [], []
    for model in models:
        with _progress(args.starts, model) as bar:
            result, material = fit_z307(model, wavelength_nm=args.wavelength_nm, dataset=args.dataset,
                                        seed=args.seed, n_starts=args.starts, progress=bar.update,
                                        fixed=_parse_pairs(args.fix, "--fix"),
                                        bounds=_parse_pairs(args.bound, "--bound", bounds=True))
        rows.append((model, result))
        materials.append(material)
        if not args.compare:
            print(format_fit_report(result))
    if args.compare:
        angles = [t for t, _ in rows[0][1].rms_log10]
        print("| model | " + " | ".join(f"{t:g} deg" for t in angles) + " | all | chi2/dof |")
        print("|---|" + "---|" * (len(angles) + 2))
        for model, r in rows:
            cells = " | ".join(f"{v:.3f}" for v in r.rms_log10.values())
            print(f"| {model} | {cells} | {r.rms_log10_total:.3f} | {r.chi2_reduced:.3g} |")
    result, material = rows[0][1], materials[0]  # --compare: the first model is the one written
    if args.output:
        save_material(args.output, material)
        print(f"wrote {args.output}")
    if args.plot:
        from materials.plots import plot_fit

        scan = read_z307(wavelength_nm=args.wavelength_nm, dataset=args.dataset)
        print(f"wrote {plot_fit(scan, result, args.plot, title=f'Aeroglaze Z307, {result.model}')}")
    if args.json:
        atomicio.write_json(args.json, {m: r.to_json() for m, r in rows})
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("material", help="evaluate, fit and inspect BRDF materials")
    sub = p.add_subparsers(dest="material_command", metavar="ACTION", required=True)

    e = sub.add_parser("eval", help="evaluate a material file or preset at given angles (CONTRACTS 4.2)")
    e.add_argument("model", metavar="MODEL", help="material JSON file or preset name")
    e.add_argument("--theta-i-deg", type=float, required=True, help="incidence angle, deg")
    e.add_argument("--theta-r-deg", type=float, nargs="+", required=True,
                   help="viewing angles, deg (negative: backscatter half-plane)")
    e.add_argument("--phi-r-deg", type=float, nargs="+", default=[0.0],
                   help="viewing azimuth, deg; 0 = specular half-plane (one value or one per theta_r)")
    e.add_argument("--polarization", choices=("s", "p", "u"), required=True)
    e.add_argument("--json", metavar="OUT.json", help="write brdf_per_sr, theta_r_deg, dhr here")
    e.add_argument("--rotation-deg", type=float, default=None,
                   help="sample rotation of an anisotropic imported table (Zemax SampleRotation), deg")
    e.set_defaults(func=cmd_eval)

    im = sub.add_parser("import", help="read a Zemax tabular .bsdf or FRED tabulated BSDF file into a material "
                                       "(CONTRACTS 5.2)")
    im.add_argument("file", metavar="FILE", help="the BSDF file (recognised by its content)")
    im.add_argument("-o", "--output", required=True, metavar="MATERIAL.json")
    im.add_argument("--name", help="material name (default: the file's stem)")
    im.add_argument("--json", metavar="REPORT.json", help="format, incidences, DHR and the file's TIS lines")
    im.set_defaults(func=cmd_import)

    ex = sub.add_parser("export", help="write a material as a Zemax tabular BSDF or FRED tabulated BSDF file "
                                       "(CONTRACTS 5.2)")
    ex.add_argument("model", metavar="MATERIAL", help="material JSON file or preset name")
    ex.add_argument("--format", choices=("zemax", "fred"), required=True)
    ex.add_argument("-o", "--output", required=True, metavar="FILE")
    ex.add_argument("--aoi-deg", type=float, nargs="+", help="incidence (specular) angles, deg")
    ex.add_argument("--radial-deg", type=float, nargs="+", help="Zemax radial angles from specular, deg")
    ex.set_defaults(func=cmd_export)

    f = sub.add_parser("fit", help="fit a model to a measured scan CSV (CONTRACTS 2)")
    f.add_argument("scan", metavar="SCAN.csv", help="a measured scan CSV (CONTRACTS 2), or a Zemax tabular .bsdf "
                   "or FRED tabulated BSDF file (its in-plane nodes)")
    f.add_argument("--wavelength-nm", type=float, help="wavelength of a BSDF file that states none")
    f.add_argument("--model", default="lambertian+k_correlation",
                   help="components joined by '+': lambertian, k_correlation, microfacet, abg, harvey_shack")
    f.add_argument("-o", "--output", required=True, metavar="MODEL.json", help="fitted material file")
    f.add_argument("--name", help="material name (default: output file stem)")
    f.add_argument("--fix", action="append", metavar="NAME=VALUE", help="hold a parameter, e.g. n=1.5")
    f.add_argument("--bound", action="append", metavar="NAME=LO:HI", help="parameter bounds")
    f.add_argument("--starts", type=int, default=6, help="multi-start count")
    f.add_argument("--seed", type=int, default=0, help="seed of the random starts")
    f.add_argument("--plot", metavar="PNG", help="measured vs fitted, per incidence angle and polarization")
    f.add_argument("--json", metavar="REPORT.json", help="machine-readable fit report")
    f.set_defaults(func=cmd_fit)

    s = sub.add_parser("show", help="print a material, its rho(theta_i) table, and plot it")
    s.add_argument("model", metavar="MODEL", help="material JSON file or preset name")
    s.add_argument("--theta-i-deg", type=float, nargs="+", default=[0, 10, 20, 30, 40, 50, 60, 70, 80, 85])
    s.add_argument("--plot", metavar="PNG")
    s.add_argument("--json", metavar="OUT.json")
    s.set_defaults(func=cmd_show)

    z = sub.add_parser("z307", help="refit the real Aeroglaze Z307 data (materials/data) and write the preset")
    z.add_argument("-o", "--output", metavar="MODEL.json", help="write the fitted material here")
    z.add_argument("--model", default=None, help="model spec (default: the preset's)")
    z.add_argument("--compare", nargs="+", metavar="SPEC", help="fit several models, print an rms table")
    z.add_argument("--wavelength-nm", type=float, default=630.79)
    z.add_argument("--dataset", choices=("control", "12_cycle"), default="control")
    z.add_argument("--fix", action="append", metavar="NAME=VALUE", help="hold a parameter, e.g. n=1.5")
    z.add_argument("--bound", action="append", metavar="NAME=LO:HI", help="parameter bounds")
    z.add_argument("--starts", type=int, default=8)
    z.add_argument("--seed", type=int, default=0)
    z.add_argument("--plot", metavar="PNG")
    z.add_argument("--json", metavar="REPORT.json")
    z.set_defaults(func=cmd_z307)
