"""The old path of `nerf_jax.samplers.spacing` (nerf_jax/samplers/spacing.py), kept for
scripts that import it: `import nerf_jax.sampling` gives that very module."""

import sys

from nerf_jax.samplers import spacing as _module

sys.modules[__name__] = _module
