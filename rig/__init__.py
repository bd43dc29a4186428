"""The bidirectional reflectometer: instrument model, control, and sim-to-real diagnosis."""
