"""``straylight rig twin``: the ray-traced reflectometer next to the fast model (docs/twin.md).

Thin layer: parse, build the rig configuration, call :func:`rig.twin.twin_scan`, print and
write twin vs fast model, optionally plot (seed paper Fig. 7 style). ``rig`` is imported inside
the command so that ``import straylight`` stays light.
"""
from __future__ import annotations

import sys
from pathlib import Path

import atomicio

RIG_OPTIONS = (("arm_mm", "sample-to-slit distance"), ("slit_width_mm", "slit width in the plane of incidence"),
               ("slit_height_mm", "slit height"), ("beam_diameter_mm", "beam 1/e^2 diameter at the sample"),
               ("beam_divergence_mrad", "Gaussian sigma of the in-plane beam divergence"),
               ("sample_width_mm", "sample extent along the plane of incidence"))


def add_parser(rig_subparsers) -> None:
    """Add ``twin`` under the ``straylight rig`` subcommands."""
    p = rig_subparsers.add_parser(
        "twin", help="trace the reflectometer's CAD twin and compare with the fast model",
        description="Ray-trace the reflectometer (sample, holder, slit plate, detector; laser beam) at each "
                    "set-point and report the BRDF it reads, P_det / (P_i Omega cos theta_r), with its Monte Carlo "
                    "standard error, next to the fast model (rig.forward). See docs/twin.md.")
    p.add_argument("--sample", required=True, metavar="NAME|MODEL.json|mirror",
                   help="material preset or file; 'mirror' (or mirror:R) for a specular sample")
    p.add_argument("--theta-i-deg", type=float, nargs="+", required=True, metavar="A", help="incidence angle(s), deg")
    p.add_argument("--theta-r-deg", type=float, nargs="+", required=True, metavar="B",
                   help="viewing angle(s), deg (negative: backscatter side)")
    p.add_argument("--polarization", nargs="+", choices=("s", "p", "u"), default=["u"], help="incident polarization(s)")
    p.add_argument("--rays", type=int, default=20_000, metavar="N", help="rays per set-point (default 20000)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--json", required=True, metavar="OUT.json", help="write twin vs fast model here")
    p.add_argument("--plot", metavar="PNG", help="log BRDF vs theta_r: twin with error bars over the fast model")
    p.add_argument("--beam-profile", choices=("gaussian", "tophat"), default="gaussian")
    p.add_argument("--estimator", choices=("auto", "nee", "walk"), default="auto",
                   help="detector estimator (auto: pilot both, keep the lower-variance one)")
    p.add_argument("--holder-rd", type=float, default=0.0, help="Lambertian reflectance of holder and post (0: absorb)")
    for field, text in RIG_OPTIONS:
        p.add_argument("--" + field.replace("_", "-"), type=float, metavar="X", help=f"{text} (default: nominal rig)")
    p.set_defaults(func=run_twin_command)


def _sample(text):
    from rig.twin import Mirror

    if text == "mirror" or text.startswith("mirror:"):
        value = text.partition(":")[2]
        try:
            return Mirror(float(value) if value else 1.0)
        except ValueError:
            raise ValueError(f"--sample {text!r}: expected mirror or mirror:R with R in [0, 1]") from None
    from materials import load_material

    return load_material(text)


def run_twin_command(args) -> int:
    from rig.instrument import NOMINAL
    from rig.twin import TwinConfig, twin_scan

    if args.rays < 1:
        raise ValueError(f"--rays must be a positive integer, got {args.rays}")
    if args.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
    for name, values in (("--theta-i-deg", args.theta_i_deg), ("--theta-r-deg", args.theta_r_deg)):
        bad = [v for v in values if not abs(v) < 90.0]
        if bad:
            raise ValueError(f"{name} {bad[0]:g} is outside (-90, 90)")
    material = _sample(args.sample)
    config = NOMINAL.replace(**{f: getattr(args, f) for f, _ in RIG_OPTIONS if getattr(args, f) is not None})
    twin = TwinConfig(beam_profile=args.beam_profile, estimator=args.estimator, holder_rd=args.holder_rd)
    scan = twin_scan(material, args.theta_i_deg, args.theta_r_deg, args.polarization, config, twin,
                     n_rays=args.rays, seed=args.seed, progress=True)
    out = scan.to_json_dict()
    out.update({"sample": args.sample, "brdf_definition": "P_detector / (P_incident * Omega_slit * cos(theta_r))",
                "rig": {k: getattr(config, k) for k in ("wavelength_nm",) + tuple(f for f, _ in RIG_OPTIONS)},
                "twin": {k: getattr(twin, k) for k in twin.__dataclass_fields__}})
    path = Path(args.json)
    atomicio.write_json(path, out)
    print(f"{'theta_i':>8} {'theta_r':>8} pol {'twin 1/sr':>11} {'stderr':>10} {'model 1/sr':>11} {'z':>6}  est")
    for pt in out["points"]:
        model = "-" if pt["model_brdf_per_sr"] is None else f"{pt['model_brdf_per_sr']:.4e}"
        z = "-" if pt["z_model_minus_twin"] is None else f"{pt['z_model_minus_twin']:+.2f}"
        print(f"{pt['theta_i_deg']:8.3f} {pt['theta_r_deg']:8.3f} {pt['polarization']:>3} "
              f"{pt['twin_brdf_per_sr']:11.4e} {pt['twin_stderr_per_sr']:10.3e} {model:>11} {z:>6}  {pt['estimator']}")
    if args.plot:
        from rig.twin import plot_twin_scan

        plot_twin_scan(scan, material, config, args.plot, title=f"{args.sample}: ray-traced twin vs fast model")
    print(f"wrote {path}" + (f" and {args.plot}" if args.plot else ""), file=sys.stderr)
    return 0
