"""The self-emission budget of a study: when parts have a ``temperature_k``, ``straylight
study`` traces the detector's self-emission in ``StudyConfig.thermal_band_um`` (reverse estimator,
to 1 %), writes thermal.json / thermal_details.json / thermal_budget.png, and the report shows the
budget by part with the narcissus term (the detector's own emission that returns to it)."""
from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

import atomicio
from straylight.thermal.model import thermal_scene
from straylight.thermal.run import thermal

STUDY_TARGET_REL_ERROR = 0.01
STUDY_MAX_SECONDS = 120.0


def has_temperatures(scene) -> bool:
    return any(float(p.meta.get("temperature_k", 0.0)) > 0 for p in scene.parts)


def thermal_step(setup, out_dir, band_um=(8.0, 12.0), seed: int = 0):
    """Trace and write the budget for ``setup.detector``; None when no part has a temperature."""
    if not has_temperatures(setup.scene):
        return None
    out = Path(out_dir)
    res = thermal(thermal_scene(setup.scene, setup.materials), band_um, target_rel_error=STUDY_TARGET_REL_ERROR,
                  seed=seed, detectors=[setup.detector], max_seconds=STUDY_MAX_SECONDS)
    atomicio.write_json(out / "thermal.json", res.to_json_dict())
    atomicio.write_json(out / "thermal_details.json", res.details())
    budget_plot(res.to_json_dict(), setup.detector, out / "thermal_budget.png")
    return res


def budget_plot(doc: dict, detector: str, path=None, ax=None):
    """Horizontal bars: band power on the detector by emitting part (1-sigma bars); the detector's own
    (narcissus) bar in red."""
    import matplotlib.pyplot as plt

    d = doc["detectors"][detector]
    rows = sorted(((k, v["power_w"], v["stderr_w"]) for k, v in d["by_part"].items()), key=lambda r: -r[1])
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(8, 0.35 * max(len(rows), 3) + 1.4), dpi=120)
    y = np.arange(len(rows))[::-1]
    ax.barh(y, [r[1] for r in rows], xerr=[r[2] for r in rows], capsize=3,
            color=["#c44e52" if r[0] == detector else "#4c72b0" for r in rows])
    ax.set_yticks(y)
    ax.set_yticklabels([r[0] + (" (narcissus)" if r[0] == detector else "") for r in rows], fontsize=8)
    lo, hi = doc["band_um"]
    ax.set_xlabel(f"band power on {detector}, {lo:g}-{hi:g} um (W)")
    ax.set_title(f"Self-emission reaching {detector}: {d['power_w']:.3e} +- {d['stderr_w']:.1e} W", fontsize=10)
    ax.grid(True, axis="x", alpha=0.3)
    if own:
        fig.tight_layout()
        if path is not None:
            atomicio.write_figure(fig, path)
            plt.close(fig)
    return ax


def narcissus_w(doc: dict, detector: str) -> tuple[float, float]:
    """(power, stderr) of the detector's own emission returning to it (0 when it has no temperature)."""
    t = doc["detectors"][detector]["by_part"].get(detector)
    return (t["power_w"], t["stderr_w"]) if t else (0.0, 0.0)


def report_section(out_dir) -> str:
    """The report's HTML section, from out_dir/thermal.json ("" when the study had no temperatures)."""
    path = Path(out_dir) / "thermal.json"
    if not path.exists():
        return ""
    doc = json.loads(path.read_text())
    parts = []
    for name, d in doc["detectors"].items():
        total = d["power_w"]
        rows = "".join(
            f"<tr><td>{html.escape(k)}</td><td>{v['power_w']:.3e}</td><td>{v['stderr_w']:.1e}</td>"
            f"<td>{(v['power_w'] / total if total > 0 else 0):.1%}</td></tr>"
            for k, v in sorted(d["by_part"].items(), key=lambda kv: -kv[1]["power_w"]))
        n, ne = narcissus_w(doc, name)
        parts.append(f"""<p>{html.escape(name)}: {total:.4e} +- {d['stderr_w']:.1e} W, irradiance
{d['irradiance_w_m2']:.4g} W/m^2. Narcissus (its own emission returning to it): {n:.3e} +- {ne:.1e} W
({(n / total if total > 0 else 0):.2%} of the total).</p>
<table><tr><th>emitting part</th><th>power (W)</th><th>1 sigma</th><th>share</th></tr>{rows}</table>""")
    lo, hi = doc["band_um"]
    return f"""<h2>Self-emission budget, {lo:g}-{hi:g} um</h2>
<figure><img src="thermal_budget.png" alt="self-emission by part" style="max-width:80%"><figcaption>Band power
reaching the detector by emitting part (Planck band radiance, Kirchhoff emissivity; reverse trace from the
detector to 1 %). Numbers in <a href="thermal.json">thermal.json</a>.</figcaption></figure>
{''.join(parts)}"""
