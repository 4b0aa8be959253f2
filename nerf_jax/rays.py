"""The old path of `nerf_jax.cameras.rays` (nerf_jax/cameras/rays.py), kept for
scripts that import it: `import nerf_jax.rays` gives that very module."""

import sys

from nerf_jax.cameras import rays as _module

sys.modules[__name__] = _module
