"""Vendored three.js bundle and the report viewer script (package data of straylight.view3d)."""
