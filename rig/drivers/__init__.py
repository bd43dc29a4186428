"""PyVISA drivers for the reflectometer's instruments.

``esp301.Esp301``: Newport ESP301-style motion controller (sample stage, arm, half-wave plate).
``sr830.Sr830``: SRS SR830-style lock-in amplifier (detector signal, laser monitor on AUX IN 1,
chopper frequency as the external reference frequency).
Each driver's module also holds its adapters to the ophyd devices' backends (:mod:`rig.devices`):
``esp301.Esp301Axis`` (one axis), ``sr830.Sr830Lockin``, ``sr830.Sr830Laser``, ``sr830.Sr830Chopper``.
``sim/*.yaml``: pyvisa-sim definitions of both, opened with
``open_resource(name, visa_library=str(SIM_DIR / "esp301.yaml") + "@sim")``.
"""
from rig.drivers.visa import (  # noqa: F401
    SIM_DIR,
    InstrumentError,
    InstrumentTimeout,
    ResponseError,
    open_resource,
    sim_library,
)
