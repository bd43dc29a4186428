"""Thermal infrared: Planck bands, emission of parts at a temperature (Kirchhoff), detector
self-emission and narcissus (reverse and forward estimators), radiative exchange factors
(CONTRACTS §7; docs/thermal.md)."""
