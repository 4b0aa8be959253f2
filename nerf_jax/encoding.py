"""The old path of `nerf_jax.fields.encodings.posenc` (nerf_jax/fields/encodings/posenc.py),
kept for scripts that import it: `import nerf_jax.encoding` gives that very module."""

import sys

from nerf_jax.fields.encodings import posenc as _module

sys.modules[__name__] = _module
