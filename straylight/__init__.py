"""Monte Carlo stray-light tracer on embreex, and the analyses built on it."""
import atomicio.numba_cache  # noqa: F401 - compiled kernels cache in the user's cache folder, not the install
