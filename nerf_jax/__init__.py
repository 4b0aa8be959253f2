"""nerf_jax: a pure-JAX, functional NeRF."""

__version__ = "0.1.0"
