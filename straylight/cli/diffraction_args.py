"""``--diffraction on|off``, shared by ``straylight trace`` and ``straylight pst`` (CONTRACTS §6.5)."""
from __future__ import annotations


def add_diffraction_arg(p) -> None:
    """``--diffraction on|off`` (trace, pst): the scene's diffracting edges bend light, or not."""
    from straylight.engine.hurb import METHOD  # not .diffraction: the parser stays light (no numba)

    p.add_argument("--diffraction", choices=("on", "off"), default="on",
                   help=f"edge diffraction at the parts marked diffraction = \"edges\" (CONTRACTS §6.5) by {METHOD}; "
                        "off: pure geometric optics (default: on)")
