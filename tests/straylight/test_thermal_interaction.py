"""Thermal's surface interaction is the engine's surface response (straylight.thermal.interaction calls
the engine's per-material functions; no copy of its own), checked against closed forms: Fresnel's
normal-incidence reflectance of a window, energy conservation at a lossless interface, and the
directional-hemispherical reflectance of a coated mirror (its lobes' albedo table plus the
specular R' after the lobes, ``Material.reflectance``), each within 4 standard errors."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

import materials
from straylight.engine import surface_geometry
from straylight.thermal import interaction

N = 40_000


def _hits(model, d, back=False, seed=1):
    """One surface part of material ``model`` hit by ``N`` rays of direction ``d`` on its front (or back)."""
    n = np.array([0.0, 0.0, 1.0])
    d = np.tile(np.asarray(d, float) / np.linalg.norm(d), (N, 1))
    facing = np.tile(n if not back else -n, (N, 1))  # toward the incoming ray
    ts = SimpleNamespace(is_role=lambda *roles: np.array(["mirror" in roles and False]), mirror_reflectance=1.0)
    sides = SimpleNamespace(material_index=np.array([[0, 0]]), models=[model])
    hit = SimpleNamespace(part=np.zeros(N, np.int64), facing=facing, front=np.full(N, not back))
    u = np.random.default_rng(seed).random((N, 8))
    return interaction.interact(ts, sides, hit, np.arange(N), d, u)


def test_window_reflects_fresnel_r_and_conserves_energy():
    n = 1.5
    window = materials.load_material({"components": [{"type": "dielectric", "n": n}]})
    out = _hits(window, [0.0, 0.0, -1.0])
    R = ((n - 1) / (n + 1)) ** 2  # Fresnel at normal incidence, 0.04
    reflected = np.mean(out.side > 0)
    assert abs(reflected - R) <= 4 * math.sqrt(R * (1 - R) / N)
    np.testing.assert_allclose(out.throughput, 1.0, rtol=1e-12)  # lossless: every branch carries E_r + E_t = 1
    assert out.delta.all()
    t = out.direction[out.side < 0]
    np.testing.assert_allclose(t, np.tile([0.0, 0.0, -1.0], (len(t), 1)), atol=1e-12)  # straight through


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0])
def test_coated_mirror_mean_weight_is_its_reflectance(theta_deg):
    coated = materials.load_material({"components": [{"type": "specular", "n": [0.96, 6.69]},
                                                     {"type": "microfacet", "alpha": 0.3, "n": 1.5, "weight": 0.5}]})
    th = math.radians(theta_deg)
    out = _hits(coated, [math.sin(th), 0.0, -math.cos(th)], seed=2)
    expected = float(coated.reflectance(np.array([th]), "u")[0])
    w = out.throughput
    # (each branch carries the total E_l + E_r here, so the spread is only rounding)
    assert abs(w.mean() - expected) <= 4 * w.std() / math.sqrt(N) + 1e-12
    assert np.all(out.side > 0)  # a mirror transmits nothing
    assert 0.0 < np.mean(out.delta) < 1.0  # both the specular and the lobe branch are taken


def test_the_branch_is_the_engines(monkeypatch):
    """The Fresnel branch goes through the engine's fresnel_branches (one copy of the physics)."""
    calls = []
    real = surface_geometry.fresnel_branches

    def spy(*args):
        calls.append(len(args[1]))
        return real(*args)

    monkeypatch.setattr(interaction, "fresnel_branches", spy)
    _hits(materials.load_material({"components": [{"type": "dielectric", "n": 1.5}]}), [0.0, 0.0, -1.0])
    assert calls == [N]
