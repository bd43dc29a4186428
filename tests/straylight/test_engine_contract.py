"""The engine's contract, over every interaction kind and material class x every estimator.

For each continuing interaction kind (straylight.engine.interactions.registry) and each class of
materials it tells apart (``surface_response``: pure scatterers and Fresnel surfaces, whose
capabilities the kind computes per material from its flags) a small scene (:data:`CONTRACT_SCENES`,
keyed by the kind's label for that class: a lit part of that kind and material, the "subject",
seen by a flat detector, with an absorber; the terminal kinds, detection and absorption, are in
every scene) and for each estimator of straylight.engine.estimators.ESTIMATORS:

- the power ledger closes (emitted = detected + absorbed + escaped, to 1e-9);
- the compiled walk equals the numpy reference walk bit for bit (where the reference implements
  the estimator);
- the detector power with the estimator on agrees with the analog walk (every estimator off, an
  independent seed) within 4 combined standard errors;
- the estimator engages on the subject's parts exactly when the subject's kind declares the
  capability it needs for the subject's material (measured from what the run wrote, not from the
  declaration).

The shipped default set (all its strategies at once) has its own row, :func:`test_the_shipped_default_set`.

A new kind (or material class) is covered by adding a scene here (the test fails for a registered
kind or class without one); a new estimator (a strategy of straylight.engine.strategies.registry) by
its row in :data:`ENGAGEMENT` (the test fails for a registered strategy without one).
:func:`test_removing_a_declaration_is_detected` deletes each declared capability in turn from the
kind's per-material rule (for the subject's material class only) and expects this check to fail;
:func:`test_a_false_declaration_is_detected` adds each undeclared one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest

from geometry.mesh import Part, Scene
from materials import load_material
from straylight.engine import second_vertex
from straylight.engine.plan import build_tables, resolve
from straylight.engine.strategies.base import TableTools
from straylight.engine.runtime import runtime
from straylight.engine.estimators import ANALOG, ESTIMATORS, options_for
from straylight.engine.interactions import INTERACTIONS, Capability, kind_for
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, make_spec, run_batch, run_batch_reference, trace

N_RAYS = 30_000  # per run with an estimator on
N_ANALOG = 120_000  # the analog walk (one run per kind, the noisiest side of each comparison)
N_REF = 1_500  # compiled vs numpy reference
SEED_ANALOG, SEED_ON = 101, 202
# with target sampling on, the walk hits on the detector straight after a subject vertex are many
# times more frequent (q = 0.5 of the draws aim at the detector, which subtends ~0.1 sr)
TARGET_ENGAGED_RATIO = 3.0


def _quad(p0, e1, e2, n=4):
    """An n x n grid of triangles over the parallelogram p0 + s e1 + t e2 (normal e1 x e2)."""
    s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    v = np.asarray(p0, float) + s.reshape(-1, 1) * np.asarray(e1, float) + t.reshape(-1, 1) * np.asarray(e2, float)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, f


def _merge(*quads):
    vs, fs, off = [], [], 0
    for v, f in quads:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


FLOOR = ((-20, -20, 0), (40, 0, 0), (0, 40, 0))  # z = 0, lit by the beam around x = 0
WALL = ((25, -20, 0), (0, 40, 0), (0, 0, 60))  # x = 25, lit by what the floor sends on
DETECTOR = ((-20, -10, 40), (20, 0, 0), (0, 20, 0))  # flat, above the floor, sees floor and wall
ABSORBER = ((-30, -30, -5), (0, 60, 0), (0, 0, 70))


def _source():
    a = math.radians(30.0)
    d = [math.sin(a), 0.0, -math.cos(a)]
    return CollimatedDisk([-20.0, 0.0, 35.0], d, d, 4.0)


def _parts(subject_role, subject_material, wall_with_subject=True, wall_material=None):
    parts = []
    if wall_with_subject:  # one L-shaped part: lit (floor) and seen-and-lit-by-the-floor (wall) faces
        parts.append(Part("subject", *_merge(_quad(*FLOOR), _quad(*WALL)), material=subject_material,
                          role=subject_role))
    else:
        parts.append(Part("subject", *_quad(*FLOOR), material=subject_material, role=subject_role))
        parts.append(Part("wall", *_quad(*WALL), material=wall_material, role="surface"))
    parts.append(Part("detector", *_quad(*DETECTOR, n=2), role="detector"))
    parts.append(Part("absorber", *_quad(*ABSORBER, n=2), role="absorber"))
    return Scene(tuple(parts))


MATTE = {"components": [{"type": "lambertian", "rd": 0.5}]}
COATED_MIRROR = {"components": [{"type": "specular", "r": 0.5}, {"type": "lambertian", "rd": 0.3}]}


@dataclass(frozen=True)
class Case:
    scene: Scene
    materials: dict
    role: str  # the subject's role
    expects: Capability  # what the estimators must do on the subject (this test's statement, not the registry's)

    @property
    def material(self):
        return self.materials.get("subject_material")

    @property
    def kind(self):
        return kind_for(self.role, self.material)

    @property
    def label(self) -> str:
        return self.kind.label(self.material)


def _matte_case():
    return Case(_parts("surface", "subject_material"), {"subject_material": load_material(MATTE, "matte")}, "surface",
                Capability.NEE | Capability.FIRST_VERTEX | Capability.SECOND_VERTEX | Capability.TARGET_MIS)


def _coated_mirror_case():
    return Case(_parts("surface", "subject_material"),
                {"subject_material": load_material(COATED_MIRROR, "coated_mirror")}, "surface",
                # NEE from the lobes; no area sampling of a Fresnel surface; its reflections into the
                # detector (light the wall scatters, reflected by the floor) counted by expected value,
                # alone or as runs of interfaces followed by splitting
                Capability.NEE | Capability.POLARIZES | Capability.REFLECTION_SPLIT | Capability.DELTA_CHAIN)


def _mirror_case():
    return Case(_parts("mirror", None, wall_with_subject=False, wall_material="wall_material"),
                {"wall_material": load_material(MATTE, "matte")}, "mirror", Capability.NONE)


#: one scene per continuing interaction kind and material class (by the registry's label,
#: Interaction.label: the kind's name, with the class where the kind tells several apart)
CONTRACT_SCENES = {
    "surface_response (scatter)": _matte_case,
    "surface_response (Fresnel)": _coated_mirror_case,
    "delta_reflection": _mirror_case,
}
TERMINAL_IN_EVERY_SCENE = ("detector", "absorber")


def _labels(kind) -> set:
    return {f"{kind.name} ({c})" if c else kind.name for c in kind.material_classes}


def test_every_registered_kind_has_a_contract_scene():
    continuing = set().union(*(_labels(kind) for kind in INTERACTIONS.values() if not kind.terminal))
    assert continuing == set(CONTRACT_SCENES), \
        "add a scene for each new interaction kind (and material class) to CONTRACT_SCENES"
    for label, build in CONTRACT_SCENES.items():
        case = build()
        assert case.label == label and label in _labels(case.kind)
    terminal = {kind_for(role) for role in TERMINAL_IN_EVERY_SCENE}
    assert terminal == {k for k in INTERACTIONS.values() if k.terminal}


_RUNS: dict = {}


def _run(case_name, estimator: EstimatorOptions, seed: int, n_rays: int = N_RAYS, record_paths: bool = False):
    """trace() of a contract scene (memoised per process: the analog runs are shared)."""
    options = TraceOptions(estimator=estimator, output=OutputOptions(record_paths=record_paths))
    key = (case_name, options, seed, n_rays)
    if key not in _RUNS:
        case = CONTRACT_SCENES[case_name]()
        _RUNS[key] = trace(case.scene, _source(), n_rays, seed=seed, materials=case.materials, options=options)
    return _RUNS[key]


def _ledger_error(res) -> float:
    total = sum(t.power_w for t in res.detectors.values()) + sum(t.power_w for t in res.absorbed.values())
    return abs(res.emitted_w - total - res.escaped.power_w) / res.emitted_w


def _last_vertex_counts(res, part_index: int) -> int:
    """Detector records whose last vertex before the detector is on part ``part_index``."""
    p = res.paths
    last = p.events[np.arange(len(p.depth)), np.clip(p.depth - 1, 0, p.events.shape[1] - 1)]
    return int(np.count_nonzero((p.depth >= 1) & (last >= 0) & (last // 4 == part_index)))


def _moves_the_exchange(case_name, estimator, on) -> bool:
    """NEE / first-vertex / reflection-split / delta-chain estimates move power through the vertex part's
    nee_exchange row (the runs other than NEE's have NEE off: nothing else writes it)."""
    return on.ledger["nee_exchange"]["subject"].power_w != 0.0


def _holds_second_vertices(case_name, estimator, on) -> bool:
    """The subject's part is in the second-vertex table and the run cast more shadow rays than NEE alone."""
    case = CONTRACT_SCENES[case_name]()
    spec = make_spec(case.scene, _source(), 1000, 0, case.materials, TraceOptions(estimator=options_for(estimator)))
    if second_vertex.unsupported(spec) is not None:
        return False
    table = second_vertex.build_table(spec, runtime().scene(spec))
    subj = spec.part_names.index("subject")
    return bool(table.from_part[subj]) and on.shadow_rays > _run(case_name, replace(ANALOG, nee=True),
                                                                  SEED_ON).shadow_rays


def _aims_at_the_target(case_name, estimator, on) -> bool:
    """Walk hits only (NEE off in both runs): target sampling multiplies those after a subject vertex."""
    case = CONTRACT_SCENES[case_name]()
    alone = _run(case_name, replace(options_for(estimator, "detector"), nee=False), SEED_ON, record_paths=True)
    off = _run(case_name, ANALOG, SEED_ON, record_paths=True)
    subj = case.scene.part_names.index("subject")
    return _last_vertex_counts(alone, subj) > TARGET_ENGAGED_RATIO * max(_last_vertex_counts(off, subj), 1)


def _chains_cross_the_subject(case_name, estimator, on) -> bool:
    """Eye chains from the detector were split at the subject's interfaces: the run cast more rays than
    one eye ray per ray of the walk (the walk's own casts are segments, not shadow rays; NEE is off)."""
    return on.shadow_rays > N_RAYS


def _casts_connections(case_name, estimator, on) -> bool:
    """Specular NEE cast connections: more casts than the split trees alone (the rest of its options)."""
    return on.shadow_rays > _run(case_name, replace(estimator.options, specular_nee=False), SEED_ON).shadow_rays


#: the contract's row of each strategy (straylight.engine.strategies.registry.STRATEGIES): how it is seen to
#: act on the subject's parts, measured from what the run wrote. A new strategy adds its row here.
ENGAGEMENT = {
    "nee": _moves_the_exchange,
    "first_vertex": _moves_the_exchange,
    "first_vertex_lobe": _moves_the_exchange,
    "second_vertex": _holds_second_vertices,
    "second_vertex_lobe": _holds_second_vertices,
    "reflection_split": _moves_the_exchange,
    "delta_chain": _moves_the_exchange,
    # entrance sampling acts on the source's rays before any hit, on no kind's parts: it must not engage
    # there (no NEE-exchange, the same walk); its own checks are in test_entrance_sampling.py
    "entrance": _moves_the_exchange,
    "target_mis": _aims_at_the_target,
    "reverse_chain": _chains_cross_the_subject,
    # it connects through analytic surfaces only (none in the contract scenes): it must not engage there
    "specular_nee": _casts_connections,
    # the light the beam puts straight on the detector, booked against the escaped row: never a kind's exchange
    "direct_area": _moves_the_exchange,
    # it joins scatter points to the beam through analytic refracting surfaces (none in the contract scenes)
    "lens_vertex": _moves_the_exchange,
}


def engaged(case_name, estimator, on) -> bool:
    """Whether ``estimator`` acted on the subject part in the run ``on`` (measured, not declared)."""
    measure = ENGAGEMENT.get(estimator.name)
    if measure is None:
        raise AssertionError(f"no engagement measure for {estimator.name}: add its row to ENGAGEMENT")
    return measure(case_name, estimator, on)


def _estimator_options(estimator):
    return options_for(estimator, "detector")


def contract_failures(case_name, estimator) -> list:
    """What breaks the contract for this kind's scene and estimator (empty: none)."""
    case = CONTRACT_SCENES[case_name]()
    out = []
    on = _run(case_name, _estimator_options(estimator), SEED_ON)
    analog = _run(case_name, ANALOG, SEED_ANALOG, N_ANALOG)
    if _ledger_error(on) > 1e-9:
        out.append(f"ledger does not close: {_ledger_error(on):.3g}")
    a, b = on.detectors["detector"], analog.detectors["detector"]
    if not (a.power_w > 0 and b.power_w > 0):
        out.append(f"no light on the detector: {a} {b}")
    elif abs(a.power_w - b.power_w) > 4 * math.hypot(a.stderr_w, b.stderr_w):
        out.append(f"biased: {a.power_w:.6g} +- {a.stderr_w:.2g} vs analog {b.power_w:.6g} +- {b.stderr_w:.2g}")
    declared = case.kind.allows(estimator.capability, case.material)
    expected = bool(case.expects & estimator.capability)
    got = engaged(case_name, estimator, on)
    if got != expected or got != declared:
        out.append(f"{estimator.name} {'engaged' if got else 'did not engage'} on {case.label} parts; "
                   f"expected {'on' if expected else 'off'}, the kind {'declares' if declared else 'does not declare'} "
                   f"{estimator.capability}")
    return out


KIND_NAMES = sorted(CONTRACT_SCENES)
EST = {e.name: e for e in ESTIMATORS}


def test_every_strategy_has_a_contract_row():
    """A registered strategy without a row (or a row without a strategy) fails here, before any trace."""
    assert set(ENGAGEMENT) == set(EST)


@pytest.mark.parametrize("estimator", sorted(EST))
@pytest.mark.parametrize("kind", KIND_NAMES)
def test_contract(kind, estimator):
    assert contract_failures(kind, EST[estimator]) == []


@pytest.mark.parametrize("kind", KIND_NAMES)
def test_analog_walk_ledger_closes(kind):
    assert _ledger_error(_run(kind, ANALOG, SEED_ANALOG, N_ANALOG)) <= 1e-9


@pytest.mark.parametrize("estimator", sorted(e.name for e in ESTIMATORS if e.reference))
@pytest.mark.parametrize("kind", KIND_NAMES)
def test_compiled_equals_reference(kind, estimator):
    case = CONTRACT_SCENES[kind]()
    est = EST[estimator]
    options = TraceOptions(estimator=_estimator_options(est))
    spec = make_spec(case.scene, _source(), N_REF, 5, case.materials, options)
    plan = resolve(options, spec)
    tools = TableTools(runtime=runtime(), intersector=None, run_batch=run_batch)
    spec = build_tables(spec, plan, tools, cache=False)  # the tables trace() would build (second-vertex, entrance)
    n_chunks = 1
    a, b = run_batch(spec, 0, n_chunks), run_batch_reference(spec, 0, n_chunks)
    assert set(a) == set(b)
    for key in a:
        if isinstance(a[key], np.ndarray):
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def _declares(label, capability) -> bool:
    case = CONTRACT_SCENES[label]()
    return case.kind.allows(capability, case.material)


def _patch_rule(monkeypatch, label, change):
    """Make the subject's kind answer ``change(capabilities)`` for materials of the subject's class only
    (its per-material rule, Interaction.capabilities_for), as a wrong declaration in the kind would."""
    case = CONTRACT_SCENES[label]()
    cls = type(case.kind)
    rule = cls.capabilities_for
    subject_class = case.kind.material_class(case.material)

    def patched(self, material=None):
        capabilities = rule(self, material)
        return change(capabilities) if self.material_class(material) == subject_class else capabilities

    monkeypatch.setattr(cls, "capabilities_for", patched)
    assert case.kind.capabilities_for(case.material) == change(rule(case.kind, case.material))


# every (kind and class, capability) declared that some estimator needs: deleting it must fail the contract
REMOVABLE = [(name, est.name) for name in KIND_NAMES for est in ESTIMATORS if _declares(name, est.capability)]


@pytest.mark.parametrize("kind,estimator", REMOVABLE)
def test_removing_a_declaration_is_detected(kind, estimator, monkeypatch):
    est = EST[estimator]
    _patch_rule(monkeypatch, kind, lambda caps: caps & ~est.capability)
    _RUNS.clear()
    try:
        failures = contract_failures(kind, est)
    finally:
        _RUNS.clear()
    assert failures, f"deleting {est.capability} from {kind} went unnoticed"


# every (kind and class, capability) not declared: declaring it falsely must fail the contract too
ADDABLE = [(name, est.name) for name in KIND_NAMES for est in ESTIMATORS
           if est.capability != Capability.NONE and not _declares(name, est.capability)]


@pytest.mark.parametrize("kind,estimator", ADDABLE)
def test_a_false_declaration_is_detected(kind, estimator, monkeypatch):
    est = EST[estimator]
    _patch_rule(monkeypatch, kind, lambda caps: caps | est.capability)
    _RUNS.clear()
    try:
        failures = contract_failures(kind, est)
    finally:
        _RUNS.clear()
    assert failures, f"declaring {est.capability} on {kind} went unnoticed"


@pytest.mark.parametrize("kind", KIND_NAMES)
def test_the_shipped_default_set(kind):
    """The contract row of the set the analyses run (``straylight.analyses.estimators``' ``default``: all its
    strategies at once, as :func:`estimator_options` gives them for the scene's materials): the ledger
    closes and the detector's power agrees with the analog walk within 4 sigma, on every kind."""
    from straylight.analyses.estimators import estimator_options

    case = CONTRACT_SCENES[kind]()
    chosen = estimator_options("default", materials=case.materials).estimator
    assert chosen.nee and chosen.first_vertex_sampling and chosen.second_vertex_sampling and chosen.delta_chain
    on = _run(kind, chosen, SEED_ON)
    analog = _run(kind, ANALOG, SEED_ANALOG, N_ANALOG)
    assert _ledger_error(on) <= 1e-9
    a, b = on.detectors["detector"], analog.detectors["detector"]
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) <= 4 * math.hypot(a.stderr_w, b.stderr_w), (kind, a, b)
