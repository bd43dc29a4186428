"""``straylight thermal`` and ``straylight exchange`` (CONTRACTS §7).

    straylight thermal SCENE.toml --band-um LO HI (--rays N | --target-rel-error E) [--seed S] --out DIR
        [--temperature-k PART=K ...] [--sweep-temperature-k PART K1 K2 ...] [--method reverse|forward]
        [--workers K | --threads K]
    straylight exchange SCENE.toml --band-um LO HI --rays N [--seed S] --out DIR

``thermal`` writes DIR/thermal.json: self-emission in the band reaching each detector, split by
the emitting part (parts with ``temperature_k``); DIR/thermal_details.json says how (method,
traced sub-bands, detector areas, rays, time, and why a --target-rel-error run stopped early). ``exchange`` writes DIR/exchange.json (Mahan's
distribution factors D_ij with standard errors, escaped fractions, hemispherical band
emissivities) and DIR/couplings.csv (eps_i A_i D_ij in m^2, for ESATAN-TMS / Thermal Desktop).
"""
from __future__ import annotations

from pathlib import Path


def add_parser(subparsers):
    p = subparsers.add_parser("thermal", help="detector self-emission in a band (Planck, Kirchhoff, narcissus)",
                              description="straylight thermal: the thermal self-emission of the instrument's parts "
                                          "(those with temperature_k) that reaches each detector in a wavelength "
                                          "band, split by emitting part; writes DIR/thermal.json and "
                                          "DIR/thermal_details.json.")
    p.add_argument("scene", help="scene file (CONTRACTS §6, parts with temperature_k)")
    _band(p)
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--rays", type=int, help="rays per detector")
    g.add_argument("--target-rel-error", type=float, help="trace until the detector power's relative error is at most E")
    p.add_argument("--method", choices=("reverse", "forward"), default="reverse",
                   help="reverse: rays from the detector pick up emission at every vertex (default, faster); "
                        "forward: the parts' emission traced by the main engine (next-event estimation at "
                        "scatter vertices)")
    p.add_argument("--max-seconds", type=float, default=600.0, help="time cap for --target-rel-error")
    p.add_argument("--temperature-k", nargs="+", default=(), metavar="PART=K",
                   help="set part temperatures (kelvin) over the scene's, in order; PART may be a shell pattern "
                        "('vane_*', '*')")
    p.add_argument("--sweep-temperature-k", nargs="+", default=None, metavar="PART K",
                   help="PART K1 K2 ...: the detector power with PART (or a pattern) at each temperature, on the "
                        "same reverse paths (DIR/thermal_sweep.csv and .json)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="output directory")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None,
                       help="K threads in this process (the thermal walks run here; same numbers for any K)")
    where.add_argument("--threads", type=int, default=None, help="the same as --workers K")
    p.set_defaults(func=run_thermal)

    e = subparsers.add_parser("exchange", help="radiative distribution factors D_ij and couplings (Mahan)",
                              description="straylight exchange: radiative exchange between the parts in a band: "
                                          "Mahan's distribution factors D_ij, escaped fractions and band "
                                          "emissivities (DIR/exchange.json), and the couplings eps_i A_i D_ij "
                                          "for thermal solvers (DIR/couplings.csv).")
    e.add_argument("scene", help="scene file (CONTRACTS §6)")
    _band(e)
    e.add_argument("--rays", type=int, required=True, help="rays in all (shared by the emitting parts)")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--out", required=True, help="output directory")
    e.set_defaults(func=run_exchange)


def _band(p):
    p.add_argument("--band-um", type=float, nargs=2, required=True, metavar=("LO", "HI"),
                   help="band in micrometres (vacuum wavelengths)")


def run_thermal(args) -> int:
    import atomicio
    from straylight import api
    from straylight.cli.cluster_args import execution
    from straylight.thermal.model import temperatures_with
    from straylight.thermal.planck import check_band

    check_band(*args.band_um)
    ts = api.thermal_scene(Path(args.scene))
    ts.temperature_k = temperatures_with(ts, args.temperature_k)
    sweep, label = _sweep(ts, args.sweep_temperature_k)
    with execution(args, in_process=True) as ex:
        res = api.thermal(ts, args.band_um, rays=args.rays, target_rel_error=args.target_rel_error, seed=args.seed,
                          method=args.method, max_seconds=args.max_seconds, sweep=[t for _, t in sweep], execution=ex)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomicio.write_json(out / "thermal.json", res.to_json_dict())
    atomicio.write_json(out / "thermal_details.json", res.details())
    if sweep:
        rows = [{"detector": det, "part": label, "temperature_k": k, "power_w": p, "stderr_w": e}
                for det, vals in res.sweep.items() for (k, _), (p, e) in zip(sweep, vals)]
        atomicio.write_json(out / "thermal_sweep.json", {"band_um": list(args.band_um), "rows": rows})
        atomicio.write_text(out / "thermal_sweep.csv", "detector,part,temperature_k,power_w,stderr_w\n" + "".join(
            f"{r['detector']},{r['part']},{r['temperature_k']:g},{r['power_w']:.9g},{r['stderr_w']:.3g}\n"
            for r in rows))
    for name, d in res.detectors.items():
        print(f"{name}: {d.power_w:.6g} +- {d.stderr_w:.2g} W, {d.irradiance_w_m2:.6g} W/m^2 "
              f"({args.band_um[0]:g}-{args.band_um[1]:g} um, {d.rays} rays)")
        for part, t in sorted(d.by_part.items(), key=lambda kv: -kv[1].power_w):
            print(f"  {part}: {t.power_w:.6g} +- {t.stderr_w:.2g} W")
    if res.stopped:
        print(res.stopped)
    for det, vals in res.sweep.items():
        for (k, _), (p, e) in zip(sweep, vals):
            print(f"  {label} at {k:g} K -> {det}: {p:.6g} +- {e:.2g} W")
    print(f"written {out}/thermal.json, {out}/thermal_details.json" + (", thermal_sweep.csv/json" if sweep else ""))
    return 0


def _sweep(ts, spec):
    """[(kelvin, temperature set)] and the part pattern of --sweep-temperature-k PART K1 K2 ..."""
    from straylight.thermal.model import temperatures_with

    if not spec:
        return [], None
    if len(spec) < 2:
        raise ValueError("--sweep-temperature-k: expected PART K1 [K2 ...]")
    part, values = spec[0], spec[1:]
    return [(float(v), temperatures_with(ts, [f"{part}={v}"])) for v in values], part


def run_exchange(args) -> int:
    from straylight import api
    from straylight.thermal.planck import check_band

    check_band(*args.band_um)
    if args.rays < 2:
        raise ValueError(f"--rays must be >= 2, got {args.rays}")
    res = api.exchange(Path(args.scene), args.band_um, rays=args.rays, seed=args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    res.write(out)
    print(res.summary())
    print(f"written {out}/exchange.json, {out}/couplings.csv")
    return 0
