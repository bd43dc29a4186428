"""Simulated reflectometer hardware: the backends behind :mod:`rig.devices` in ``--sim`` mode.

The simulated lock-in reads what the real one would (seed paper section 2, PHYSICS §4):

    V = g P_laser Omega cos(theta_r) f(theta_i, theta_r, phi_r, pol)

with ``g`` the detector gain (V/W), ``Omega = slit_w slit_h / arm^2`` and ``f`` the BRDF seen
through the instrument (``rig.forward.predict_brdf`` with the chosen effects) or, with
``ideal=True``, the material's own BRDF. Each reading gets Gaussian noise of standard deviation

    sigma_V = sqrt((noise_rel V)^2 + (g P_laser Omega noise_floor_per_sr)^2)

(defaults 5 % and 3e-6 1/sr: ~5 % near the peak, rising to ~30 % at BRDF ~ 1e-5 1/sr, the
seed paper's observed spread). A constant power floor, so in BRDF units the floor rises as
1 / cos(theta_r). The noise of reading ``k`` at a stage position is drawn from
``default_rng([seed, stage, arm, hwp, k])`` (positions in 1e-4 deg), so a scan's numbers do
not depend on the order of the points, on interruptions or on ``--resume``.

Motion and settling take simulated time (a :class:`SimClock`), never wall time. Faults can be
injected for tests: a stalled axis, a mute lock-in, a laser power dip.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from rig.drivers import InstrumentTimeout
from rig.drivers.sr830 import REFERENCE_UNLOCK, SENSITIVITY_V
from rig.instrument import RigConfig

#: HWP angle (deg) selecting each polarization: a half-wave plate at 45 deg turns s into p.
HWP_DEG = {"s": 0.0, "p": 45.0}


class SimClock:
    """Simulated time in seconds; ``sleep`` advances it instantly."""

    def __init__(self):
        self.t_s = 0.0

    def sleep(self, seconds: float) -> None:
        self.t_s += max(float(seconds), 0.0)


class SimAxis:
    """One simulated rotation axis. ``stall_after_moves=k``: the (k+1)-th move never finishes."""

    def __init__(self, name: str, clock: SimClock, velocity_deg_s: float = 10.0, position_deg: float = 0.0):
        self.name = name
        self.clock = clock
        self.velocity_deg_s = velocity_deg_s
        self._position = float(position_deg)
        self.target = float(position_deg)
        self.stall_after_moves: int | None = None
        self.n_moves = 0
        self.stalled = False
        self.synchronous = True

    def move(self, position_deg: float) -> None:
        self.target = float(position_deg)
        self.n_moves += 1
        if self.stall_after_moves is not None and self.n_moves > self.stall_after_moves:
            self.stalled = True
            return
        self.clock.sleep(abs(self.target - self._position) / self.velocity_deg_s)
        self._position = self.target

    def position(self) -> float:
        return self._position

    def done(self) -> bool:
        return not self.stalled

    def stop(self) -> None:
        self.target = self._position

    def sleep(self, seconds: float) -> None:
        self.clock.sleep(seconds)


class SimLaser:
    """Power-stabilised laser with a power monitor. ``dip(...)`` simulates a power drop."""

    def __init__(self, power_w: float = 5e-3):
        self.nominal_w = power_w
        self._power_w = power_w
        self._listeners: list = []  # callables told of every clock step
        self._timers: list = []
        self.synchronous = True

    def power_w(self) -> float:
        return self._power_w

    def add_listener(self, fn) -> None:
        self._listeners.append(fn)

    def _set(self, power_w: float) -> None:
        self._power_w = power_w
        for fn in list(self._listeners):
            fn(power_w)

    def dip(self, fraction: float = 0.1, duration_s: float = 0.2) -> None:
        """Drop to ``fraction`` of nominal now; come back after ``duration_s`` of wall time
        (wall time, because a suspended RunEngine advances no simulated time)."""
        self._set(self.nominal_w * fraction)
        timer = threading.Timer(duration_s, self._set, args=(self.nominal_w,))
        timer.daemon = True
        self._timers.append(timer)
        timer.start()


class SimChopper:
    synchronous = True

    def __init__(self, frequency_hz: float = 1000.0):
        self._frequency_hz = frequency_hz

    def frequency_hz(self) -> float:
        return self._frequency_hz


@dataclass
class SimFaults:
    """Faults to inject, counted in lock-in readings (0-based index of the reading)."""

    lockin_timeout_at_reading: int | None = None
    laser_dip_at_reading: int | None = None
    laser_dip_fraction: float = 0.05
    laser_dip_duration_s: float = 0.2
    #: the chopper's reference is lost at this reading, for ``reference_unlock_duration_s`` of
    #: simulated time (``None``: never; ``float('inf')``: for good). Readings while unlocked are garbage.
    reference_unlock_at_reading: int | None = None
    reference_unlock_duration_s: float = 2.0
    on_reading: list = field(default_factory=list)  # callables fn(n_readings) run before each reading


class SimLockin:
    """Simulated SR830 in front of a photodetector looking through the slit.

    Parameters
    ----------
    rig : SimRig whose stage/arm/HWP/laser state sets the signal.
    """

    def __init__(self, rig: "SimRig", sensitivity_index: int = 17, time_constant_s: float = 0.1):
        self.rig = rig
        self.sensitivity_index = sensitivity_index
        self.time_constant_s = time_constant_s
        self.filter_slope = 1
        self.n_readings = 0
        self._overload = False
        self._unlocked_until_s = -1.0
        self._unlock_latched = False
        self._key: tuple[int, int, int] | None = None  # the positions of the current noise stream
        self._k = 0
        self.synchronous = True

    # settings -----------------------------------------------------------------
    @property
    def sensitivity_v(self) -> float:
        return SENSITIVITY_V[self.sensitivity_index]

    @sensitivity_v.setter
    def sensitivity_v(self, full_scale_v: float) -> None:
        idx = int(np.searchsorted(np.asarray(SENSITIVITY_V), full_scale_v * (1 - 1e-9)))
        self.sensitivity_index = min(idx, len(SENSITIVITY_V) - 1)

    def settle_time_s(self) -> float:
        return (5.0, 7.0, 9.0, 10.0)[self.filter_slope] * self.time_constant_s

    def sleep(self, seconds: float) -> None:
        self.rig.clock.sleep(seconds)

    def start_acquisition(self) -> None:
        """A new point's readings begin: restart the per-position reading counter, so a point
        re-measured after a suspension or a resume reads the same noise as the first time."""
        self._key, self._k = None, 0

    def discard_reading(self) -> None:
        """The device rejected the last reading (autorange changed the range and reads again):
        the retry reuses its noise draw, so the values do not depend on the range history."""
        self._k = max(self._k - 1, 0)

    def reference_unlocked(self) -> bool:
        """True while the simulated chopper reference is lost (SimFaults.reference_unlock_*)."""
        return self.rig.clock.t_s < self._unlocked_until_s

    def status_flags(self) -> list[str]:
        """The LIAS? names set since the last call (latched like the SR830's, cleared by reading)."""
        out = ["output overload"] if self._overload else []
        if self._unlock_latched or self.reference_unlocked():
            out.append(REFERENCE_UNLOCK)
        self._overload = False
        self._unlock_latched = False
        return out

    # signal ---------------------------------------------------------------------
    def true_signal_v(self) -> float:
        """Noise-free detector signal at the current state, V."""
        rig = self.rig
        return rig.gain_v_per_w * rig.laser.power_w() * rig.config.solid_angle_sr * rig.brdf_cos_now()

    def output(self, which: str = "x") -> float:
        rig = self.rig
        faults = rig.faults
        for fn in faults.on_reading:
            fn(self.n_readings)
        if faults.lockin_timeout_at_reading is not None and self.n_readings >= faults.lockin_timeout_at_reading:
            raise InstrumentTimeout("simulated SR830: no reply to 'OUTP? 1' within 0.05 s")
        if faults.laser_dip_at_reading is not None and self.n_readings == faults.laser_dip_at_reading:
            rig.laser.dip(faults.laser_dip_fraction, faults.laser_dip_duration_s)
        if faults.reference_unlock_at_reading is not None and self.n_readings == faults.reference_unlock_at_reading:
            self._unlocked_until_s = rig.clock.t_s + faults.reference_unlock_duration_s
        unlocked = self.reference_unlocked()
        if unlocked:
            self._unlock_latched = True
        self.n_readings += 1
        key = rig.state_key()
        if key != self._key:
            self._key, self._k = key, 0
        rng = np.random.default_rng([rig.seed, *key, self._k])
        self._k += 1
        v_true = self.true_signal_v()
        floor_v = rig.gain_v_per_w * rig.laser.power_w() * rig.config.solid_angle_sr * rig.noise_floor_per_sr
        sigma = np.hypot(rig.noise_rel * v_true, floor_v)
        v = v_true + sigma * rng.standard_normal()
        if unlocked:  # no reference: the demodulator drifts; what it reads means nothing
            v *= 0.3
        full = self.sensitivity_v
        if abs(v) > full:
            self._overload = True
            v = float(np.clip(v, -full, full))
        return float(v)


class SimRig:
    """The whole simulated instrument: three axes, laser, chopper, lock-in, and a sample.

    Parameters
    ----------
    material : a materials model (``brdf(wi, wo, polarization)``) or None for no sample
        (an instrument-signature scan reads only the noise floor and stray background).
    config : RigConfig; the solid angle and, through ``rig.forward``, the instrument effects.
    seed : int, seeds every reading's noise.
    ideal : read the material BRDF itself instead of the rig forward model.
    effects : effects passed to ``rig.forward.predict_brdf``.
    gain_v_per_w : detector + transimpedance gain, V per W at the slit.
    noise_rel, noise_floor_per_sr : the noise model of the module docstring.
    stray_per_sr : stray background of the rig (BRDF-equivalent at normal view), also without sample.
    """

    def __init__(self, material=None, config: RigConfig | None = None, *, seed: int = 0, ideal: bool = False,
                 effects=(), laser_power_w: float = 5e-3, gain_v_per_w: float = 1000.0,
                 noise_rel: float = 0.05, noise_floor_per_sr: float = 3e-6, stray_per_sr: float = 0.0):
        self.material = material
        self.config = config or RigConfig()
        self.seed = int(seed)
        self.ideal = ideal
        self.effects = tuple(effects)
        self.gain_v_per_w = gain_v_per_w
        self.noise_rel = noise_rel
        self.noise_floor_per_sr = noise_floor_per_sr
        self.stray_per_sr = stray_per_sr
        self.clock = SimClock()
        self.axes = {name: SimAxis(name, self.clock) for name in ("sample", "arm", "hwp")}
        self.laser = SimLaser(laser_power_w)
        self.chopper = SimChopper()
        self.lockin = SimLockin(self)
        self.faults = SimFaults()
        self._brdf_cache: dict[tuple, float] = {}

    def prefetch(self, points) -> None:
        """Evaluate the BRDF of many plan points in one vectorised forward-model call and cache
        it by stage/arm/HWP position (speed only: the values are those :meth:`brdf_now` computes).

        points : sequence of ``(theta_i_deg, polarization, theta_r_deg, phi_r_deg)``.
        """
        if self.material is None or not len(points):
            return
        from rig.plans import HWP_DEG, Point, arm_deg

        pts = [Point(*p) for p in points]
        keys = [tuple(int(round(v * 1e4)) for v in (p.theta_i_deg, arm_deg(p), HWP_DEG[p.polarization]))
                for p in pts]
        ti = np.array([p.theta_i_deg for p in pts])
        # the state a point sets, seen back through geometry_now (stage, |arm - stage|, side)
        rel = np.array([k[1] - k[0] for k in keys]) / 1e4
        tr = np.abs(rel)
        pr = np.where(rel >= 0, 0.0, 180.0)
        pol = np.array([p.polarization for p in pts])
        ok = (np.abs(ti) < 90) & (tr < 90)
        f = np.zeros(len(pts))
        if ok.any():
            if self.ideal:
                from materials.base import directions_from_angles

                for code in ("s", "p"):
                    sel = ok & (pol == code)
                    if sel.any():
                        wi, wo = directions_from_angles(np.radians(ti[sel]), np.radians(tr[sel]), np.radians(pr[sel]))
                        f[sel] = np.asarray(self.material.brdf(wi, wo, code), float)
            else:
                from rig.forward import predict_brdf

                f[ok] = np.asarray(predict_brdf(self.material, ti[ok], tr[ok], pr[ok], pol[ok], self.config,
                                                effects=self.effects), float)
        for key, value in zip(keys, f):
            self._brdf_cache[key] = float(value) + self.stray_per_sr

    def state_key(self) -> tuple[int, int, int]:
        """Stage, arm and HWP positions in 1e-4 deg (the key of the noise stream)."""
        sample, arm, hwp = (int(round(self.axes[a].position() * 1e4)) for a in ("sample", "arm", "hwp"))
        return sample, arm, hwp

    def geometry_now(self):
        """(theta_i_deg, theta_r_deg, phi_r_deg, s_fraction) from the stage, arm and HWP positions.

        The arm angle is measured from the incoming beam's reverse direction, so the arm sits at
        ``theta_i + theta_r`` on the specular side (phi_r = 0) and ``theta_i - theta_r`` on the
        backscatter side (phi_r = 180).
        """
        stage = self.axes["sample"].position()
        arm = self.axes["arm"].position()
        rel = arm - stage
        theta_r = abs(rel)
        phi_r = 0.0 if rel >= 0 else 180.0
        hwp = np.radians(self.axes["hwp"].position())
        s_fraction = float(np.cos(2 * hwp) ** 2)  # HWP at angle a rotates linear s by 2a
        return stage, theta_r, phi_r, s_fraction

    def brdf_now(self) -> float:
        """BRDF (1/sr) the detector sees now; cached per stage/arm/HWP position."""
        key = self.state_key()
        if key not in self._brdf_cache:
            self._brdf_cache[key] = self._brdf_at_state()
        return self._brdf_cache[key]

    def _brdf_at_state(self) -> float:
        theta_i, theta_r, phi_r, s_frac = self.geometry_now()
        if self.material is None or abs(theta_i) >= 90 or theta_r >= 90:
            f = 0.0
        else:
            f_s = self._brdf(theta_i, theta_r, phi_r, "s") if s_frac > 1e-12 else 0.0
            f_p = self._brdf(theta_i, theta_r, phi_r, "p") if s_frac < 1 - 1e-12 else 0.0
            f = s_frac * f_s + (1 - s_frac) * f_p
        return f + self.stray_per_sr

    def brdf_cos_now(self) -> float:
        _, theta_r, _, _ = self.geometry_now()
        return self.brdf_now() * max(np.cos(np.radians(theta_r)), 0.0)

    def _brdf(self, theta_i_deg, theta_r_deg, phi_r_deg, pol) -> float:
        if self.ideal:
            from materials.base import directions_from_angles

            wi, wo = directions_from_angles(np.radians(theta_i_deg), np.radians(theta_r_deg), np.radians(phi_r_deg))
            return float(np.asarray(self.material.brdf(wi, wo, pol))[0])
        from rig.forward import predict_brdf

        out = predict_brdf(self.material, np.atleast_1d(theta_i_deg), np.atleast_1d(theta_r_deg),
                           np.atleast_1d(phi_r_deg), pol, self.config, effects=self.effects)
        return float(np.asarray(out).ravel()[0])
