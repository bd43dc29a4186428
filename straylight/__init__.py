"""Monte Carlo stray-light tracer on embreex, and the analyses built on it."""
