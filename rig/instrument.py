"""The reflectometer's nominal geometry (seed paper section 2; PHYSICS §4).

Two coaxial rotation stages: the first turns the sample (incidence angle), the
second orbits the detector arm in the plane of incidence. A collimated 532 nm
laser beam of 1/e^2 diameter ``beam_diameter_mm`` lights the sample; a slit of
``slit_width_mm`` (in the plane of incidence) by ``slit_height_mm`` (out of
plane) at ``arm_mm`` from the sample sets the detector's solid angle.

:class:`RigConfig` holds the geometry plus three alignment errors that are zero
on a perfect rig (``stage_offset_deg``, ``arm_offset_deg``, ``sample_tilt_deg``).
The instrument effects of CONTRACTS §3 (``rig.effects``) act by changing these
fields or by post-processing the forward model; the nominal rig (``NOMINAL``)
is the "plausible geometry when unknown" of PHYSICS §4.

CSV metadata (CONTRACTS §2) carries the geometry as ``rig.*`` keys;
:meth:`RigConfig.from_metadata` reads them, falling back to the nominal value for
every key a file lacks.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass


class RigConfigError(ValueError):
    """A rig parameter is missing its meaning (non-numeric, non-finite or out of range)."""


# metadata key -> RigConfig field. The first five are CONTRACTS §2 keys; the
# others are written by this project and read when present.
METADATA_KEYS = {
    "rig.arm_mm": "arm_mm",
    "rig.slit_width_mm": "slit_width_mm",
    "rig.slit_height_mm": "slit_height_mm",
    "rig.beam_diameter_mm": "beam_diameter_mm",
    "rig.sample_width_mm": "sample_width_mm",
    "rig.beam_divergence_mrad": "beam_divergence_mrad",
}

_POSITIVE = ("wavelength_nm", "arm_mm", "slit_width_mm", "slit_height_mm", "beam_diameter_mm", "sample_width_mm")


@dataclass(frozen=True)
class RigConfig:
    """Geometry of the bidirectional reflectometer (lengths in mm, angles in deg/mrad).

    Parameters
    ----------
    wavelength_nm : laser wavelength (the scan's own column wins where it exists).
    arm_mm : sample-to-slit distance.
    slit_width_mm : slit width in the plane of incidence (200 um in the seed paper).
    slit_height_mm : slit height out of the plane of incidence.
    beam_diameter_mm : laser beam 1/e^2 diameter at the sample (Gaussian profile,
        intensity sigma = diameter / 4).
    beam_divergence_mrad : Gaussian sigma of the incident beam's in-plane angular spread.
    sample_width_mm : sample extent along the plane of incidence; the footprint
        ``beam / cos(theta_i)`` beyond it is lost (overfill).
    stage_offset_deg : zero offset of the sample stage: true incidence = set-point + offset.
    arm_offset_deg : zero offset of the detector arm: true viewing angle = set-point + offset
        (signed in-plane angle, positive toward the specular side's larger theta_r).
    sample_tilt_deg : sample normal tilted out of the plane of incidence.
    """

    wavelength_nm: float = 532.0
    arm_mm: float = 200.0
    slit_width_mm: float = 0.2
    slit_height_mm: float = 5.0
    beam_diameter_mm: float = 1.5
    beam_divergence_mrad: float = 0.0
    sample_width_mm: float = 25.4
    stage_offset_deg: float = 0.0
    arm_offset_deg: float = 0.0
    sample_tilt_deg: float = 0.0

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise RigConfigError(f"rig parameter {field.name} must be a finite number, got {value!r}")
            object.__setattr__(self, field.name, float(value))
        for name in _POSITIVE:
            if getattr(self, name) <= 0:
                raise RigConfigError(f"rig parameter {name} must be > 0, got {getattr(self, name)!r}")
        if self.beam_divergence_mrad < 0:
            raise RigConfigError(f"rig parameter beam_divergence_mrad must be >= 0, got {self.beam_divergence_mrad!r}")

    @property
    def beam_sigma_mm(self) -> float:
        """Gaussian sigma of the beam's intensity profile: 1/e^2 radius / 2."""
        return self.beam_diameter_mm / 4.0

    @property
    def solid_angle_sr(self) -> float:
        """Nominal detector solid angle, slit area / arm^2 (seed paper: the slit area sets it)."""
        return self.slit_width_mm * self.slit_height_mm / self.arm_mm**2

    @property
    def angular_width_mrad(self) -> float:
        """In-plane angle over which the arm sees a mirror's reflected beam, ~(beam + slit) / arm
        (PHYSICS §4: 8.5 mrad for the nominal rig)."""
        return 1e3 * (self.beam_diameter_mm + self.slit_width_mm) / self.arm_mm

    def replace(self, **changes) -> "RigConfig":
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_metadata(cls, metadata: dict | None, where: str = "metadata") -> "RigConfig":
        """Build from CSV metadata (CONTRACTS §2 ``rig.*`` keys); missing keys take nominal values.

        Unknown keys are ignored (the file may carry other metadata). A value that is not a
        positive finite number raises :class:`RigConfigError` naming the key and ``where``.
        """
        kwargs = {}
        for key, field in METADATA_KEYS.items():
            if metadata is None or key not in metadata:
                continue
            raw = metadata[key]
            try:
                value = float(raw)
            except (TypeError, ValueError):
                raise RigConfigError(f"{where}: {key} must be a number, got {raw!r}") from None
            kwargs[field] = value
        try:
            return cls(**kwargs)
        except RigConfigError as exc:
            raise RigConfigError(f"{where}: {exc}") from None

    def to_metadata(self) -> dict:
        """The ``rig.*`` metadata keys (strings) a scan file should carry for this rig.

        Alignment errors are unknown to the instrument and are not written.
        """
        return {key: repr(getattr(self, field)) for key, field in METADATA_KEYS.items()}


NOMINAL = RigConfig()
