"""The old path of `nerf_jax.samplers.sampling` (nerf_jax/samplers/sampling.py), kept for
scripts that import it: `import nerf_jax.sampling` gives that very module."""

import sys

from nerf_jax.samplers import sampling as _module

sys.modules[__name__] = _module
