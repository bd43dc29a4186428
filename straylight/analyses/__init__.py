"""Analyses built on the tracer: PST sweeps, stray-light path reports, critical and
illuminated objects, design sweeps, and the study report."""
