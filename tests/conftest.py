import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
# CAD tessellations are cached on disk (geometry.cad_cache); tests start cold unless they test the cache.
os.environ.setdefault("STRAYLIGHT_CACHE", "off")
