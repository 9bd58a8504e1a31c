"""`python3 -m wearfit_usd.kernels`: compile (or load from numba's cache) every kernel ahead of the first run."""
from wearfit_usd.kernels import warm_up

print("numba kernels ready" if warm_up() else "numba not installed: numpy paths in use")
