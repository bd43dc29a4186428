"""BRDF models for black coatings, importance sampling, fitting and measured scans."""
