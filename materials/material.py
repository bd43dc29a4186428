"""Materials: a named sum of components at one wavelength, and material files (CONTRACTS §5).

A material file is JSON::

    {"name": "z302_sample_a", "wavelength_nm": 532.0,
     "description": "free text (optional)", "provenance": "free text (optional)",
     "components": [{"type": "lambertian", "rd": 0.03}, {"type": "k_correlation", ...}]}

Unknown keys are an error. ``description`` and ``provenance`` are the only keys added
to CONTRACTS §5 (free text, ignored by the physics). ``wavelength_nm`` is optional for
materials whose components do not depend on wavelength (e.g. an inline Lambertian in a
scene file); components with a ``wavelength_nm`` field left unset take the material's
(the material passes it at build time).

A material is refused when its directional-hemispherical reflectance reaches 1 at any
integer theta_i in 0..89 deg, for s or p incidence (seed paper Eq. 3).
"""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Optional

import numpy as np

import atomicio
from atomicio.inputs import InputFileError, read_input_text
from materials.albedo import directional_hemispherical_reflectance
from materials.base import MaterialError, Sample
from materials.composite import _TABLE_THETA, Composite
from materials.energy_checked import check_key, passed_before, remember_pass
from materials.flags import ComponentFlags, flags_of, union
from materials.registry import build_component
from materials.sampling import check_real

LIBRARY_DIR = Path(__file__).resolve().parent / "library"
MAX_COMPONENTS = 64  # 100 000 components took minutes to load and check
TOP_LEVEL_KEYS = ("name", "wavelength_nm", "components", "description", "provenance")
ENERGY_CHECK_THETA_I_DEG = np.arange(0.0, 90.0, 1.0)


@dataclass(frozen=True, eq=False)
class Material:
    """A named sum of BRDF components (the Brdf protocol of materials.base).

    Parameters
    ----------
    name : str
    wavelength_nm : float or None
        Passed to every component whose ``wavelength_nm`` is unset.
    components : tuple of models
    description, provenance : str, optional
        Free text, kept in the file.
    """

    name: str
    wavelength_nm: Optional[float]
    components: tuple
    description: Optional[str] = None
    provenance: Optional[str] = None

    def __post_init__(self):
        where = f"material {self.name!r}"
        if self.wavelength_nm is not None:
            object.__setattr__(
                self, "wavelength_nm", check_real(where, "wavelength_nm", self.wavelength_nm, lo=0.0, lo_open=True)
            )
        comps = []
        for i, c in enumerate(tuple(self.components)):
            fields = {f.name for f in dataclasses.fields(c)} if dataclasses.is_dataclass(c) else set()
            if "wavelength_nm" in fields and getattr(c, "wavelength_nm") is None:
                if self.wavelength_nm is None:
                    if getattr(c, "wavelength_optional", False):
                        comps.append(c)
                        continue
                    raise MaterialError(
                        f"{where}: components[{i}] ({getattr(c, 'type_name', type(c).__name__)}) "
                        "needs wavelength_nm: give it in the material or the component"
                    )
                c = dataclasses.replace(c, wavelength_nm=self.wavelength_nm)
            comps.append(c)
        if not comps:
            raise MaterialError(f"{where}: 'components' must be a non-empty list")
        smooth = [i for i, c in enumerate(comps) if flags_of(c) & ComponentFlags.DELTA]
        if len(smooth) > 1:
            raise MaterialError(
                f"{where}: components[{smooth[1]}]: at most one specular or dielectric component per material"
            )
        comps = _with_substrate(comps, comps[smooth[0]] if smooth else None)
        object.__setattr__(self, "components", tuple(comps))

    # ------------------------------------------------------------ smooth part and lobes

    @property
    def smooth(self):
        """The material's delta component (``specular`` or ``dielectric``), or None."""
        for c in self.components:
            if flags_of(c) & ComponentFlags.DELTA:
                return c
        return None

    @property
    def flags(self) -> ComponentFlags:
        """The union of the components' declared flags (materials.flags); the tracer chooses the
        surface interaction from them (straylight.engine.interactions.registry)."""
        return union(self.components)

    @property
    def lobes(self) -> tuple:
        """The scatter components (everything but the delta component)."""
        return tuple(c for c in self.components if not flags_of(c) & ComponentFlags.DELTA)

    def lobe_reflectance(self, theta_i, polarization: str = "u") -> np.ndarray:
        """Directional-hemispherical reflectance of the scatter lobes at theta_i (radians),
        interpolated from the composite's albedo table (2.5 deg grid); zeros without lobes."""
        th = np.atleast_1d(np.asarray(theta_i, float))
        if self.composite is None:
            return np.zeros(th.shape)
        if polarization == "u":
            return 0.5 * (self.lobe_reflectance(th, "s") + self.lobe_reflectance(th, "p"))
        table = self.composite._table(polarization).sum(axis=0)
        return np.interp(np.clip(th, 0.0, np.pi / 2), _TABLE_THETA, table)

    def smooth_coefficients(self, cos_i, back: bool = False):
        """Amplitude coefficients (:class:`materials.smooth.Coefficients`) of the delta component
        at incidence cosines ``cos_i`` (n,), after the scatter lobes have taken their energy:
        powers scaled by ``g = max(0, 1 - rho_lobes / (R + T))`` for s and p separately
        (CONTRACTS §5.1). None without a delta component."""
        smooth = self.smooth
        if smooth is None:
            return None
        c = np.clip(np.atleast_1d(np.asarray(cos_i, float)), 0.0, 1.0)
        coef = smooth.coefficients(c, back=back)
        if self.composite is None:
            return coef
        theta = np.arccos(c)
        g = []
        for pol, R, T in (("s", coef.R_s, coef.T_s), ("p", coef.R_p, coef.T_p)):
            tot = R + T
            rho = self.lobe_reflectance(theta, pol)
            g.append(np.where(tot > 0, np.clip(1.0 - rho / np.where(tot > 0, tot, 1.0), 0.0, 1.0), 0.0))
        return coef.scaled(*g)

    def reflectance(self, theta_i, polarization: str = "u") -> np.ndarray:
        """Directional-hemispherical reflectance including the specular part: lobes + R'."""
        th = np.atleast_1d(np.asarray(theta_i, float))
        rho = self.lobe_reflectance(th, polarization)
        coef = self.smooth_coefficients(np.cos(th))
        return rho if coef is None else rho + coef.reflectance(polarization)

    def transmittance(self, theta_i, polarization: str = "u") -> np.ndarray:
        """Power transmitted by the delta component (T', zero without a dielectric)."""
        th = np.atleast_1d(np.asarray(theta_i, float))
        coef = self.smooth_coefficients(np.cos(th))
        return np.zeros(th.shape) if coef is None else coef.transmittance(polarization)

    @cached_property
    def composite(self) -> Optional[Composite]:
        """The scatter lobes as one Composite (None when the material is only a delta component)."""
        lobes = self.lobes
        return Composite(lobes) if lobes else None

    @property
    def reciprocal(self) -> bool:
        return self.composite is None or self.composite.reciprocal

    # ------------------------------------------------------------ Brdf protocol

    # The protocol covers the scatter lobes only; the delta component (``smooth``) is handled
    # by the tracer's surface interaction through ``smooth_coefficients``.

    def brdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """Sum of the scatter lobes' BRDFs in 1/sr (no cos). wi, wo : (n, 3)."""
        if self.composite is None:
            return np.zeros(len(np.asarray(wi)))
        return self.composite.brdf(wi, wo, polarization)

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        """One-sample MIS over the scatter lobes; u : (n, 3) uniforms (weight 0 without lobes)."""
        if self.composite is None:
            n = len(np.asarray(wi))
            return Sample(wo=np.tile([0.0, 0.0, 1.0], (n, 1)), weight=np.zeros(n), pdf_per_sr=np.zeros(n))
        return self.composite.sample(wi, u, polarization)

    def pdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        if self.composite is None:
            return np.zeros(len(np.asarray(wi)))
        return self.composite.pdf(wi, wo, polarization)

    def brdf_pdf(self, wi, wo, polarization: str = "u") -> tuple[np.ndarray, np.ndarray]:
        """``(brdf(wi, wo), pdf(wi, wo))``, the scatter lobes' shared quantities made once (the same bits)."""
        if self.composite is None:
            return self.brdf(wi, wo, polarization), self.pdf(wi, wo, polarization)
        return self.composite.brdf_pdf(wi, wo, polarization)

    def albedo(self, theta_i, polarization: str = "u") -> np.ndarray:
        """Directional-hemispherical reflectance rho of the scatter lobes at theta_i (radians);
        :meth:`reflectance` adds the specular part."""
        if self.composite is None:
            return np.zeros(np.shape(theta_i))
        return directional_hemispherical_reflectance(self.composite, theta_i, polarization)

    def check_energy(self, where: Optional[str] = None) -> None:
        """Raise MaterialError if rho(theta_i) >= 1 at any integer theta_i in 0..89 deg (s or p), or at
        a table's own incidence nodes and the midpoints between them (a spike between nodes)."""
        if self.composite is None:
            return  # a delta component alone: R + T <= 1 by construction (Fresnel, r <= 1, weight <= 1)
        key = check_key(self)
        if passed_before(key):  # the same material passed before (materials.energy_checked)
            return
        for c in self.lobes:  # tables check their own nodes, the midpoints and every sample rotation
            table_check = getattr(c, "check_energy_table", None)
            if table_check is not None:
                table_check(where or f"material {self.name!r}")
        nodes = [np.asarray(c.check_nodes_deg(), float) for c in self.lobes if hasattr(c, "check_nodes_deg")]
        theta_deg = np.unique(np.concatenate([ENERGY_CHECK_THETA_I_DEG, *nodes])) if nodes else ENERGY_CHECK_THETA_I_DEG
        theta_deg = theta_deg[theta_deg < 90.0]
        theta = np.deg2rad(theta_deg)
        rho_max = 0.0
        for pol in ("s", "p"):
            # a coarse grid (<~1 % for beta-centred lobes, ~10 % for grazing microfacet lobes
            # at 89 deg), refined with the default grid wherever it comes near 1
            rho = directional_hemispherical_reflectance(self.composite, theta, pol, 32, 48)
            near = (rho > 0.8) & (rho < 1.25)  # outside, the coarse answer is not in doubt
            if np.any(near):
                rho[near] = directional_hemispherical_reflectance(self.composite, theta[near], pol)
            k = int(np.argmax(rho))
            if rho[k] >= 1.0:
                raise MaterialError(
                    f"{where or 'material ' + repr(self.name)}: not energy-conserving: directional-"
                    f"hemispherical reflectance {rho[k]:.4f} >= 1 at theta_i = "
                    f"{theta_deg[k]:g} deg ({pol}-polarized)"
                )
            rho_max = max(rho_max, float(rho[k]))
        remember_pass(key, rho_max)

    def to_dict(self) -> dict:
        """The material-file dict (CONTRACTS §5); component wavelengths equal to the material's are omitted."""
        out = {"name": self.name}
        if self.wavelength_nm is not None:
            out["wavelength_nm"] = self.wavelength_nm
        if self.description is not None:
            out["description"] = self.description
        if self.provenance is not None:
            out["provenance"] = self.provenance
        comps = []
        for c in self.components:
            d = c.to_dict()
            if d.get("wavelength_nm") is not None and d["wavelength_nm"] == self.wavelength_nm:
                del d["wavelength_nm"]
            comps.append(d)
        out["components"] = comps
        return out


def _with_substrate(comps, smooth):
    """Components that model particles on a surface (``particulate``) learn the index of the
    surface under them from the material's delta component, unless they were given one."""
    out = []
    for c in comps:
        if getattr(c, "needs_substrate", False) and smooth is not None and c.substrate_unset:
            c = c.with_substrate(smooth)
        out.append(c)
    return out


# ---------------------------------------------------------------- files


def list_presets() -> list[str]:
    """Names of the material presets shipped in materials/library/."""
    return sorted(p.stem for p in LIBRARY_DIR.glob("*.json"))


def material_from_dict(data, where: str = "material", name: Optional[str] = None, check_energy: bool = True) -> Material:
    """Build a Material from a CONTRACTS §5 dict; errors name ``where`` and the component index/key."""
    if not isinstance(data, dict):
        raise MaterialError(f"{where}: a material must be a JSON object / table, got {type(data).__name__}")
    unknown = sorted(set(data) - set(TOP_LEVEL_KEYS))
    if unknown:
        raise MaterialError(
            f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(TOP_LEVEL_KEYS)}"
        )
    comps_in = data.get("components")
    if not isinstance(comps_in, list) or not comps_in:
        raise MaterialError(f"{where}: 'components' must be a non-empty list")
    if len(comps_in) > MAX_COMPONENTS:
        raise MaterialError(f"{where}: {len(comps_in)} components is above {MAX_COMPONENTS} (a material is a sum of a "
                            f"few lobes; every component is evaluated at every scatter event)")
    mat_name = data.get("name", name if name is not None else "unnamed")
    if not isinstance(mat_name, str):
        raise MaterialError(f"{where}: 'name' must be a string")
    for key in ("description", "provenance"):
        if key in data and not isinstance(data[key], str):
            raise MaterialError(f"{where}: {key!r} must be a string")
    wavelength_nm = data.get("wavelength_nm")
    if wavelength_nm is not None:
        wavelength_nm = check_real(where, "wavelength_nm", wavelength_nm, lo=0.0, lo_open=True)
    comps = []
    for i, entry in enumerate(comps_in):
        here = f"{where}: components[{i}]"
        try:
            comps.append(build_component(entry, where=here))
        except MaterialError as exc:
            msg = str(exc)
            raise MaterialError(msg if msg.startswith(here) else f"{here}: {msg}") from None
        except (TypeError, ValueError) as exc:
            raise MaterialError(f"{here}: {exc}") from None
    try:
        mat = Material(
            name=mat_name,
            wavelength_nm=wavelength_nm,
            components=tuple(comps),
            description=data.get("description"),
            provenance=data.get("provenance"),
        )
    except MaterialError as exc:
        raise MaterialError(f"{where}: {exc}") from None
    if check_energy:
        mat.check_energy(where)
    return mat


def load_material(source, name: Optional[str] = None, check_energy: bool = True) -> Material:
    """A Material from a preset name, a JSON file path, a dict, or a Material (returned as is).

    Parameters
    ----------
    source : str, os.PathLike, dict or Material
        A string that names an existing file (or ends in ``.json``) is read as a file;
        otherwise it is a preset name (:func:`list_presets`). A dict is a material
        as in CONTRACTS §5 or a scene file's inline ``[material.NAME]`` table.
    name : str, optional
        Name for a dict without ``name`` (the scene's material key).
    check_energy : bool
        Refuse materials with rho(theta_i) >= 1 (default True).
    """
    if isinstance(source, Material):
        return source
    if isinstance(source, dict):
        where = f"material {name!r}" if name else "material"
        return material_from_dict(source, where=where, name=name, check_energy=check_energy)
    if not isinstance(source, (str, os.PathLike)):
        raise MaterialError(f"load_material: expected a preset name, a path or a dict, got {type(source).__name__}")
    path = Path(source)
    if not path.exists() and not str(source).endswith(".json"):
        preset = LIBRARY_DIR / f"{source}.json"
        if not preset.exists():
            raise MaterialError(
                f"unknown material {str(source)!r}: not a file and not a preset ({', '.join(list_presets())})"
            )
        path = preset
    try:
        text = read_input_text(path, "material file")
    except InputFileError as exc:
        raise MaterialError(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise MaterialError(f"{path}: material file is not UTF-8 text ({exc.reason})") from None
    except OSError as exc:
        raise MaterialError(f"{path}: cannot read material file ({exc.strerror or exc})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MaterialError(f"{path}:{exc.lineno}:{exc.colno}: invalid JSON: {exc.msg}") from None
    return material_from_dict(data, where=str(path), name=path.stem, check_energy=check_energy)


def save_material(path, material: Material, check_energy: bool = True) -> Path:
    """Write a material file atomically (:func:`atomicio.write_json`)."""
    path = Path(path)
    if check_energy:
        material.check_energy(str(path))
    return atomicio.write_json(path, material.to_dict(), fsync=False)
