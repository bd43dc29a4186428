"""Sim-to-real diagnosis: fit the sample through the rig model, then explain the rest.

Method (Kennedy & O'Hagan-style calibration with a discrepancy made of *named* effect
terms; PHYSICS §4 "diagnosis practice"):

1. **Data and noise.** Points with ``brdf_per_sr > 2 x standard error`` (the standard
   error is ``brdf_std_per_sr / sqrt(n_repeats)``; a point without a std only needs
   ``brdf_per_sr > 0``) are *usable*: every gap and fit uses only these (the "above its
   own noise" rule). The relative error of the mean is smoothed by a straight line in
   (log10 BRDF, log relative error) through the scan's own std values, because a std
   from 3 readings is itself uncertain to ~50 %; residuals are
   ``log10(measured / simulated) / sigma_log10``. A file without std values gets 5 %.
2. **Hold-out.** Default: the middle incidence angle (index (n-1)//2 of the sorted list)
   and the highest one; with one or two angles, the highest is held out unless that
   leaves no training data. ``--holdout-theta-i`` overrides.
3. **Baseline.** Lambertian + one or two K-correlation lobes (shared refractive index n,
   s and p fitted jointly through :mod:`rig.forward` on the nominal rig) on the training
   angles; one or two lobes chosen by BIC.
4. **Candidates.** Every catalogue effect (or ``--effects``) is fitted *jointly with the
   material* (warm start from the baseline, a few starts for the effect's parameters),
   and scored by ``delta_bic`` (BIC = chi^2 + k ln N on the training points) and by
   the held-out gap before and after.
5. **Forward selection.** The best candidate (lowest BIC) is kept if it lowers BIC by more
   than :data:`BIC_THRESHOLD` *and* improves the prediction of the held-out angles: their
   chi^2 falls by more than :data:`HELDOUT_CHI2_GAIN` and their gap falls; repeat with the
   rest on top (only the best :data:`MAX_RETRIED` candidates that helped alone are
   retried). Candidates that helped alone but add nothing once another was selected are
   reported as *confounded* with it (e.g. an offset and the slit width both act in
   the specular core). An effect whose fitted parameter sits at a bound of its plausible
   range (``at_bound`` in the JSON) is never selected: the residual is larger than any
   plausible instrument error of that kind, which usually means the material model fails.
   After each selection, the candidates that did not help alone are screened again on top
   of the new model (effect parameters only, material fixed) and join the pool when they now
   lower chi^2 by more than the BIC penalty: a smaller effect can be masked by a bigger one
   (a 1 deg tilt under 7 % polarization leakage fits to zero tilt alone).
   Finally a backward pass refits without each selected effect in turn and drops it when
   removing it costs less than :data:`BIC_THRESHOLD` in BIC or less than
   :data:`HELDOUT_CHI2_GAIN` in held-out chi^2 (``dropped_effects``), and the final model is
   refitted from fresh material starts with the effects held, then jointly
   (:func:`refit_fresh_material`): the baseline material has bent to imitate the effects and
   can hold the joint fit in a local minimum (a 1 deg tilt on the z302_sample_a preset
   ended at 0.89 deg and 1.8x the noise level without it, at 1.00 deg and 1.03x with it).
   Then each selected effect that has a *twin* (stage and arm offsets) is checked against it
   with the rest of the model in place (:mod:`rig.diagnose.twins`): replaced when the data
   prefer the twin, kept when they prefer it, reported confounded when they cannot tell
   (``twin_checks`` in the JSON).
6. **Regions.** ``specular_core`` (|theta_r - theta_i| <= 0.5 deg in the plane),
   ``shoulder`` (0.5..5 deg), ``wing`` (beyond), and where present ``grazing`` (viewing
   beyond 75 deg, outside core and shoulder) and ``near_retro`` (backscatter side within
   10 deg of the incident beam). One entry per region, incidence angle and polarization.

Files: :mod:`~rig.diagnose.regions` (regions and the per-region table),
:mod:`~rig.diagnose.fast_material` (the fitted sample on cached node geometry),
:mod:`~rig.diagnose.params` (parameters, bounds from each model's own file, model, fit),
:mod:`~rig.diagnose.problem` (the scan prepared: noise, hold-out, least-squares fit),
:mod:`~rig.diagnose.starts`, :mod:`~rig.diagnose.candidates` (baseline and effect fits),
:mod:`~rig.diagnose.heldout` (held-out scoring, candidate table), :mod:`~rig.diagnose.selection`
(forward/backward selection, :func:`diagnose`), :mod:`~rig.diagnose.twins` (telling twin
effects apart: stage vs arm offset), :mod:`~rig.diagnose.json_doc` (OUT.json),
:mod:`~rig.diagnose.tasks` (independent fits on the caller's executor).

The *noise level* is the gap a perfect model would leave: the RMS over the usable points
of the measured standard error in dex, ``std / (sqrt(n) brdf ln 10)``.
"""
from rig.diagnose.candidates import BIC_THRESHOLD, fit_baseline, fit_many, fit_with_effect
from rig.diagnose.fast_material import FitMaterial, NodeCache, node_geometry, q_factor_real
from rig.diagnose.heldout import HELDOUT_CHI2_GAIN
from rig.diagnose.json_doc import GAP_METRIC, to_json
from rig.diagnose.params import Fit, Model, ParamSpec, effect_specs, material_specs
from rig.diagnose.problem import DEFAULT_RELATIVE_STD, SIGMA_FLOOR_DEX, DiagnoseError, Problem, default_holdout
from rig.diagnose.regions import REGION_ORDER, classify_regions, region_table
from rig.diagnose.selection import MAX_RETRIED, Diagnosis, diagnose

__all__ = ["BIC_THRESHOLD", "DEFAULT_RELATIVE_STD", "GAP_METRIC", "HELDOUT_CHI2_GAIN", "MAX_RETRIED", "REGION_ORDER",
           "SIGMA_FLOOR_DEX", "DiagnoseError", "Diagnosis", "Fit", "FitMaterial", "Model", "NodeCache", "ParamSpec",
           "Problem", "classify_regions", "default_holdout", "diagnose", "effect_specs", "fit_baseline", "fit_many",
           "fit_with_effect", "material_specs", "node_geometry", "q_factor_real", "region_table", "to_json"]
