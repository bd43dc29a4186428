"""Reader for the real Aeroglaze Z307 BRF files (UA LOFT ``bsdf-tools``, MIT licence).

The files in ``materials/data/`` (see ``README_z307.txt`` there for source, commit
and licence) hold the in-plane bidirectional reflectance *factor* of Z307 black
paint measured in the UA Remote Sensing Group "Black Lab". Columns:
``src_z src_a view_z view_a BRF(lambda_1) BRF(lambda_2) ...``, degrees.

Conversion to a :class:`materials.scan.Scan` (CONTRACTS §1-2):

- BRDF = BRF / pi (1/sr).
- ``theta_i = src_z``, ``theta_r = view_z``; ``phi_r = view_a - src_a - 180`` (mod 360):
  ``view_a = 180`` (opposite the source) is the forward/specular half-plane,
  ``phi_r = 0``; ``view_a = 0`` is backscatter, ``phi_r = 180``.
- The 0/45 rows at the start and end of each file are reference checks of the
  calibration (source at the normal) and are skipped.
- Polarization: not stated in the source, treated as unpolarized ``"u"``.
- Uncertainty: the files give none. We attach ``brdf_std_per_sr = relative_std * brdf``
  with ``relative_std = 0.05`` by default: a stated, assumed 5 % (absolute BRF
  calibration against a NIST 0/45 standard is typically 2-3 %, and a 5 deg sampled
  arm on a lobe that changes by 0.1-0.3 dex per 5 deg adds a few % from pointing).
  The two 0/45 reference rows of the control file agree to 0.1 %, so the repeat
  noise is far below this; the 5 % is a model-error floor, not a measured std.
  ``n_repeats`` is 1 (unknown).
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from materials.scan import Scan, ScanError

#: Data sets shipped in ``materials/data`` (keys accepted by :func:`read_z307`).
Z307_FILES = {
    "control": "control_set_Z307_on_Al6061T6_20260910_sample.txt",
    "12_cycle": "12_cycle_set_Z307_on_Al_20260911_sample.txt",
}
Z307_SOURCE = (
    "github.com/ua-loft/bsdf-tools @ b572b087765cafb8f5c7189b91f918703d997520 "
    "(MIT, Copyright (c) 2025 LOFT Group; measured by J. P. Krell, UA Remote Sensing Group Black Lab)"
)
DEFAULT_WAVELENGTH_NM = 630.79
DEFAULT_RELATIVE_STD = 0.05


def z307_path(dataset: str = "control") -> Path:
    """Path of a shipped Z307 data file (``"control"`` or ``"12_cycle"``)."""
    if dataset not in Z307_FILES:
        raise ValueError(f"dataset: unknown Z307 data set {dataset!r}; known: {', '.join(Z307_FILES)}")
    return Path(str(resources.files("materials") / "data" / Z307_FILES[dataset]))


def read_z307(path=None, wavelength_nm: float = DEFAULT_WAVELENGTH_NM,
              relative_std: float = DEFAULT_RELATIVE_STD, dataset: str = "control") -> Scan:
    """Read a Z307 BRF file into an unpolarized in-plane :class:`Scan`.

    Parameters
    ----------
    path : path-like, optional
        A file in the LOFT Black Lab format; default: the shipped ``dataset``.
    wavelength_nm : float
        Which BRF column to use: the nearest column within 1 nm.
    relative_std : float
        Assumed relative standard uncertainty attached to every point (see module doc).
    dataset : str
        ``"control"`` (12x12 sample, 631/852 nm) or ``"12_cycle"`` (small FOV, 386-1059 nm).

    Returns
    -------
    Scan
        brdf_per_sr = BRF / pi, theta_r_deg = view_z, phi_r_deg 0 (forward) or 180 (back).
    """
    if not relative_std >= 0:
        raise ValueError(f"relative_std must be >= 0, got {relative_std}")
    path = Path(path) if path is not None else z307_path(dataset)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        raise ScanError("no such file", path) from None
    header_at = next((i for i, l in enumerate(lines) if l.split()[:1] == ["src_z"]), None)
    if header_at is None:
        raise ScanError("no 'src_z src_a view_z view_a ...' header line", path, 1)
    header = lines[header_at].split()
    if header[:4] != ["src_z", "src_a", "view_z", "view_a"] or len(header) < 5:
        raise ScanError(f"unexpected header {header}", path, header_at + 1)
    try:
        wavelengths = np.array([float(h.removesuffix("nm")) for h in header[4:]])
    except ValueError:
        raise ScanError(f"wavelength columns must look like '630.79nm': {header[4:]}", path, header_at + 1) from None
    col = int(np.argmin(np.abs(wavelengths - wavelength_nm)))
    if abs(wavelengths[col] - wavelength_nm) > 1.0:
        raise ValueError(f"wavelength_nm: {wavelength_nm} not in {path.name} (columns: {wavelengths.tolist()} nm)")
    rows = []
    for lineno, line in enumerate(lines[header_at + 1:], start=header_at + 2):
        cells = line.split()
        if not cells:
            continue
        if len(cells) != len(header):
            raise ScanError(f"row has {len(cells)} values, header has {len(header)}", path, lineno)
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise ScanError(f"non-numeric value in {cells}", path, lineno) from None
    data = np.array(rows).reshape(-1, len(header))
    src_z, src_a, view_z, view_a = data[:, 0], data[:, 1], data[:, 2], data[:, 3]
    keep = src_z > 0  # the 0/45 rows are calibration checks
    brf = data[keep, 4 + col]
    brdf = brf / np.pi
    phi_r_deg = np.mod(view_a[keep] - src_a[keep] - 180.0, 360.0)
    sample = lines[1].strip() if header_at > 1 else ""
    metadata = {
        "sample": f"Aeroglaze Z307 on Al ({sample})" if sample else "Aeroglaze Z307 on Al",
        "source": f"{path.name} from {Z307_SOURCE}",
        "wavelength_column_nm": f"{wavelengths[col]:g}",
        "quantity": "BRF/pi from in-plane BRF; polarization not stated, taken as unpolarized",
        "brdf_std": f"assumed {relative_std:g} x brdf (not in the source file)",
    }
    return Scan(
        wavelength_nm=np.full(brdf.shape, wavelengths[col]),
        polarization=np.full(brdf.shape, "u"),
        theta_i_deg=src_z[keep],
        theta_r_deg=view_z[keep],
        phi_r_deg=phi_r_deg,
        brdf_per_sr=brdf,
        brdf_std_per_sr=relative_std * np.abs(brdf),
        n_repeats=np.ones(brdf.shape, dtype=np.int64),
        metadata=metadata,
        path=path,
    )


#: Model used for the shipped preset ``materials/library/z307.json`` (docs/materials-fitting.md).
Z307_PRESET_MODEL = "lambertian+microfacet"


def fit_z307(model: str = Z307_PRESET_MODEL, wavelength_nm: float = DEFAULT_WAVELENGTH_NM,
             dataset: str = "control", seed: int = 0, n_starts: int = 8, fixed=None, bounds=None,
             progress=None):
    """Fit ``model`` to the real Z307 data; returns ``(FitResult, Material)``.

    The material is named ``z307`` and carries its provenance (data source, wavelength,
    model, rms log10 residual per incidence angle) in its ``provenance`` text.
    """
    from materials.fit import fit  # fit imports the model modules; keep the reader light

    scan = read_z307(wavelength_nm=wavelength_nm, dataset=dataset)
    result = fit(scan, model, seed=seed, n_starts=n_starts, fixed=fixed, bounds=bounds, progress=progress)
    rms = ", ".join(f"{t:g} deg: {v:.3f}" for (t, _), v in result.rms_log10.items())
    provenance = (
        f"Fit of {model} to the real in-plane BRF of Aeroglaze Z307 (BRDF = BRF/pi), data set "
        f"'{dataset}' ({Z307_FILES[dataset]}), column {result.wavelength_nm:g} nm, from {Z307_SOURCE}. "
        f"Unpolarized data; assumed std {DEFAULT_RELATIVE_STD:g} x BRDF. rms log10(model/measured) per "
        f"incidence angle: {rms}; all {result.rms_log10_total:.3f} dex, chi2/dof {result.chi2_reduced:.3g}. "
        f"Refit: `straylight material z307 -o materials/library/z307.json`."
    )
    material = result.material(
        "z307",
        description="Aeroglaze Z307 flat black polyurethane on Al 6061-T6; matte-paint grazing forward lobe "
                    "(microfacet) over a diffuse floor. n is an effective index (unpolarized data do not "
                    "separate it from the lobe weight). Valid for theta_i 10-70 deg, theta_r <= 75 deg; "
                    "the retro-reflection rise near theta_r = -theta_i is not modelled.",
        provenance=provenance,
    )
    return result, material
