"""nerf_jax: a pure-JAX, functional NeRF."""

# NERF_JAX_EMULATE takes effect here, before anything is compiled (backend/precision.py).
from nerf_jax.backend import precision as _precision  # noqa: F401

__version__ = "0.1.0"
