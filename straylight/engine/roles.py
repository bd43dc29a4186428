"""Part roles as the kernels see them: what a hit on the part does first (the hit stage's switch).
What a continuing hit (surface, mirror) does next is the part's surface interaction
(straylight.engine.interactions)."""
ROLE_CODES = {"surface": 0, "mirror": 1, "absorber": 2, "detector": 3}
ROLE_SURFACE, ROLE_MIRROR, ROLE_ABSORBER, ROLE_DETECTOR = 0, 1, 2, 3
ROLE_NAMES = {code: name for name, code in ROLE_CODES.items()}
