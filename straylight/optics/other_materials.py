"""Optical materials that lens files name but the glass makers' catalogues lack.

The catalogues opticalglass reads (Schott, Ohara, Hoya, CDGM, Sumita) are optical *glasses*; lens files
also name crystals and fused silica from OpticStudio's MISC, CORNING and HERAEUS catalogues (``SILICA``,
``F_SILICA``, ``C79-80``, ``CAF2``, ``SAPPHIRE``) and a few vendor glasses (``B270``). Each here comes
from a published dispersion formula (the Sellmeier form n^2 - 1 = sum B_i l^2 / (l^2 - C_i^2), l in um):

- fused silica: I. H. Malitson, J. Opt. Soc. Am. 55, 1205 (1965), 0.21-3.71 um (nd = 1.4585);
- calcium fluoride: I. H. Malitson, Appl. Opt. 2, 1103 (1963), 0.23-9.7 um (nd = 1.4338);
- sapphire, ordinary ray: I. H. Malitson, J. Opt. Soc. Am. 52, 1377 (1962), 0.2-5.5 um (nd = 1.7682);
- Schott B 270 (Superwite crown): no Sellmeier published in the datasheet's summary; nd = 1.5230,
  vd = 58.5 as a model glass (opticalglass' ModelGlass, the model rayoptics uses for model glasses).

Each becomes an opticalglass medium (``InterpolatedMedium`` on 1 nm steps over the formula's range, or
``ModelGlass``), so rayoptics traces it like a catalogue glass.
"""
from __future__ import annotations

import math

#: name -> (label with its source, B (3,), C (3,) in um, valid range in nm)
SELLMEIER = {
    "fused silica": ("fused silica (Malitson 1965)", (0.6961663, 0.4079426, 0.8974794),
                     (0.0684043, 0.1162414, 9.896161), (210.0, 3710.0)),
    "calcium fluoride": ("CaF2 (Malitson 1963)", (0.5675888, 0.4710914, 3.8484723),
                         (0.050263605, 0.1003909, 34.649040), (230.0, 9700.0)),
    "sapphire": ("sapphire, ordinary ray (Malitson 1962)", (1.4313493, 0.65054713, 5.3414021),
                 (0.0726631, 0.1193242, 18.028251), (200.0, 5500.0)),
}
#: name -> (nd, vd) of vendor glasses given by their datasheet's index and Abbe number
MODEL = {"schott b 270": (1.5230, 58.5)}
#: the names lens files use (upper case, spaces and underscores as written) -> a key of SELLMEIER or MODEL
ALIASES = {
    "SILICA": "fused silica", "F_SILICA": "fused silica", "FUSED_SILICA": "fused silica",
    "FUSEDSILICA": "fused silica", "FUSED SILICA": "fused silica", "C79-80": "fused silica",
    "C7980": "fused silica", "CORNING7980": "fused silica", "SUPRASIL": "fused silica", "SUPRASIL1": "fused silica",
    "SUPRASIL2": "fused silica", "SUPRASIL3001": "fused silica", "HPFS": "fused silica", "UVFS": "fused silica",
    "QUARTZ_FUSED": "fused silica",
    "CAF2": "calcium fluoride", "CALCIUM_FLUORIDE": "calcium fluoride",
    "LITHOTEC-CAF2": "calcium fluoride",  # Schott's CaF2 (Lithotec), gone from its current catalogue
    "SAPPHIRE": "sapphire", "AL2O3": "sapphire",
    "B270": "schott b 270", "B_270": "schott b 270", "B-270": "schott b 270",
}


def sellmeier_index(key: str, wavelength_nm: float) -> float:
    """n of SELLMEIER[key] at ``wavelength_nm`` (the three-term Sellmeier equation)."""
    _, b, c, _ = SELLMEIER[key]
    l2 = (float(wavelength_nm) / 1000.0) ** 2
    return math.sqrt(1.0 + sum(bi * l2 / (l2 - ci * ci) for bi, ci in zip(b, c)))


def known_name(name: str) -> str | None:
    """The key of SELLMEIER or MODEL for a lens file's glass name, or None."""
    return ALIASES.get(name.strip().upper())


def medium(name: str):
    """An opticalglass medium for the lens file's glass ``name``, or None when it is not one of these."""
    key = known_name(name)
    if key is None:
        return None
    if key in MODEL:
        from opticalglass.modelglass import ModelGlass

        nd, vd = MODEL[key]
        return ModelGlass(nd, vd, name.strip(), cat="datasheet nd, vd")
    from opticalglass.opticalmedium import InterpolatedMedium

    label, _, _, (lo, hi) = SELLMEIER[key]
    wvls = [float(w) for w in range(int(lo), int(hi) + 1)]
    return InterpolatedMedium(name.strip(), wvls=wvls, rndx=[sellmeier_index(key, w) for w in wvls], cat=label)
