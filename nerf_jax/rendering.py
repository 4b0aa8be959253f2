"""The old path of `nerf_jax.render.compositing` (`nerf_jax.rendering.composite` stays
importable): `import nerf_jax.rendering` gives that very module."""

import sys

from nerf_jax.render import compositing as _module

sys.modules[__name__] = _module
