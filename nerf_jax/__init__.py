"""nerf_jax: a pure-JAX, functional NeRF."""

from nerf_jax import precision as _precision  # noqa: F401  (NERF_JAX_EMULATE, before any jit)

__version__ = "0.1.0"
