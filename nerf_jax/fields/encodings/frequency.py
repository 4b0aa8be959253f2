"""The frequency bands of the viewing directions (direction encoding 'frequency', the default):
posenc.py's bands, config.dir_encode_dims of them (protocol.DirectionSettings), applied by the
Field when model.view_dependent."""

from nerf_jax.fields import protocol, registry
from nerf_jax.fields.encodings.posenc import Frequency


def build(settings, shared):
  """The Frequency encoding of the directions (protocol.DirectionSettings; shared: unused)."""
  del shared
  if settings.dir_encode_dims < 0:
    raise ValueError(f"config.dir_encode_dims={settings.dir_encode_dims}: use 0 (the directions "
                     "alone) or more bands")
  return Frequency(settings.dir_encode_dims)


# Its settings are top-level fields shared with 'sh' (config.dir_encode_dims, dir_encoding).
DIRECTION_ENCODING = registry.Encoding("frequency", protocol.DirectionSettings, build, section="")
