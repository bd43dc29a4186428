"""BRDF models for black coatings, importance sampling, fitting and measured scans.

Importing the package registers every component type (materials.registry).
"""
import atomicio.numba_cache  # noqa: F401 - compiled kernels cache in the user's cache folder, not the install
from materials.abg import Abg
from materials.albedo import directional_hemispherical_reflectance
from materials.base import Brdf, MaterialError, Sample
from materials.composite import Composite
from materials.fresnel import fresnel_reflectance, polarization_factor
from materials.harvey_shack import HarveyShack
from materials.kcorrelation import KCorrelation
from materials.lambertian import Lambertian
from materials.microfacet import Microfacet
from materials.tabulated import Tabulated
from materials.smooth import Dielectric, Specular
from materials.particulate import Particulate
from materials.material import Material, list_presets, load_material, material_from_dict, save_material

__all__ = [
    "Abg",
    "Brdf",
    "Composite",
    "Dielectric",
    "HarveyShack",
    "KCorrelation",
    "Lambertian",
    "Material",
    "Microfacet",
    "MaterialError",
    "Particulate",
    "Sample",
    "Specular",
    "Tabulated",
    "directional_hemispherical_reflectance",
    "fresnel_reflectance",
    "list_presets",
    "load_material",
    "material_from_dict",
    "polarization_factor",
    "save_material",
]
