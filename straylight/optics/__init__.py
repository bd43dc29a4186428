"""Optical prescriptions in: CODE V ``.seq`` and Zemax ``.zmx`` lens files as exact scenes (docs/optics.md).

- :mod:`straylight.optics.reader`: the file (via rayoptics) -> surfaces in the scene frame
- :mod:`straylight.optics.scene_build`: surfaces -> scene tables (parts, edges, stop, image, pupil)
- :mod:`straylight.optics.output`: ``prescription.json``, ``scene.toml`` and the ``optics info`` table
"""
