"""Density activations: raw network output -> volume density sigma >= 0.

raw: float [...] any value; the result sigma is float32 [...] (or float64 for float64 raw).
The value and gradient stay finite for finite raw, and for raw = ±inf the value is inf or 0 with a
finite gradient (compositing clamps an infinite density, see volume/quadrature.MAX_DENSITY).

Each activation first promotes raw to at least float32: compositing is float32 anyway, and in
float16 exp overflows at raw = 11.1, after which the backward pass multiplies inf by the zero
gradient of an opaque sample (NaN).
"""

import jax
import jax.numpy as jnp

# exp(88) is the largest power of e below float32's max (3.4e38); clamping there keeps exp finite.
_MAX_EXP_ARG = 88.0


def _to_float32(raw):
  """raw as float32, or wider if it already is."""
  raw = jnp.asarray(raw)
  return raw.astype(jnp.promote_types(raw.dtype, jnp.float32))


def relu(raw):
  """The reference's choice: max(raw, 0). Zero gradient for raw < 0 ("dead" empty space)."""
  return jax.nn.relu(_to_float32(raw))


def shifted_softplus(raw, shift=-1.0):
  """softplus(raw + shift) (mip-NeRF): smooth, never dead; the shift starts the field nearly empty.

  jax.nn.softplus is log1p(exp(x)) written stably (logaddexp), finite for any finite x.
  """
  return jax.nn.softplus(_to_float32(raw) + shift)


def safe_exp(raw):
  """exp(raw) with the argument clamped at 88 so neither value nor gradient overflows float32.

  The clamp is applied with a straight-through-free `minimum`: above 88 the gradient is 0, which
  is the honest gradient of the clamped function.
  """
  return jnp.exp(jnp.minimum(_to_float32(raw), _MAX_EXP_ARG))


DENSITY_ACTIVATIONS = {"relu": relu, "softplus": shifted_softplus, "exp": safe_exp}


def density_activation(name):
  """The activation called `name` ('relu', 'softplus' or 'exp')."""
  if name not in DENSITY_ACTIVATIONS:
    raise ValueError(f"unknown density activation {name!r}; "
                     f"choose one of {sorted(DENSITY_ACTIVATIONS)}")
  return DENSITY_ACTIVATIONS[name]
