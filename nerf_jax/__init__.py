"""nerf_jax: a pure-JAX, functional NeRF."""

# Before jax reads XLA_FLAGS: native float atomics on the jaxlibs that lost them.
from nerf_jax.backend import gpu_atomics as _gpu_atomics

_gpu_atomics.apply()

# NERF_JAX_EMULATE takes effect here, before anything is compiled (backend/precision.py).
from nerf_jax.backend import precision as _precision  # noqa: E402,F401

__version__ = "0.1.0"
