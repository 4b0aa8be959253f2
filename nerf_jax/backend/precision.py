"""Matmul precision: one policy for every backend, and a CPU emulation of a GPU's arithmetic.

On NVIDIA GPUs since Ampere, XLA's float32 matmuls and convolutions at the default precision
round their inputs to TF32 (a 10-bit mantissa, relative error ~5e-4 per input), and XLA compiles
float32 division to an approximate division (up to 2 ulps). A CPU does neither, so code that
is only tested on a CPU can be wrong on every GPU.

The policy:
  * geometry, data and metrics (rays and cameras, NDC, the scene tracer, pose refinement, the
    visual hull, compositing's reductions, SSIM) use full float32: their matmuls, einsums and
    convolutions go through `einsum`, `matmul` and `convolve` here, at Precision.HIGHEST. A camera
    turned in TF32 is off by ~0.3 px at 400 px.
  * the networks run at `model.matmul_precision` (NETWORK_PRECISIONS): the backend's fast
    default unless a config asks for more.

The emulation (for tests; `NERF_JAX_EMULATE=tf32,div` in the environment before nerf_jax is
imported, or `emulate()`), on the CPU only:
  * 'tf32': every float32 dot_general and convolution not at Precision.HIGHEST rounds its inputs
    to TF32 (`jax.lax.reduce_precision(x, 8, 10)`), as a GPU does;
  * 'div': every float32 division x/y is x times a reciprocal of y one ulp too large (exact for
    powers of two): up to 3.3 ulps (measured), a little worse than a GPU's approximate division
    (up to 2), so that what survives it survives the GPU's.
A geometry function that forgets the helper then fails its tolerance on a CPU as it would on a
GPU. The emulation changes how XLA lowers these primitives, so it must be on before the first
compilation (jit caches what it compiled).
"""

import os
import warnings

import jax
import jax.numpy as jnp
import numpy as np

HIGHEST = jax.lax.Precision.HIGHEST

# model.matmul_precision -> the precision of the networks' matmuls. On a GPU 'default' and
# 'high' are both TF32; 'highest' is full float32. On a TPU 'high' is three bfloat16 passes.
NETWORK_PRECISIONS = {"default": None, "high": jax.lax.Precision.HIGH, "highest": HIGHEST}

ENVIRONMENT = "NERF_JAX_EMULATE"  # comma-separated: 'tf32', 'div'
EMULATIONS = ("tf32", "div")
_installed = set()


def _on_host(*operands):
  """Whether every operand is a NumPy array or scalar (no jax array, no tracer)."""
  return not any(isinstance(x, jax.Array) for x in operands)  # tracers are jax.Arrays too


def einsum(subscripts, *operands):
  """jnp.einsum in full float32 on every backend (geometry, data, metrics); NumPy operands
  stay on the host, in NumPy (exact in their own dtype, float64 included)."""
  if _on_host(*operands):
    return np.einsum(subscripts, *operands)
  return jnp.einsum(subscripts, *operands, precision=HIGHEST)


def matmul(a, b):
  """a @ b in full float32 on every backend (geometry, data, metrics); NumPy operands stay on
  the host, in NumPy."""
  if _on_host(a, b):
    return np.matmul(a, b)
  return jnp.matmul(a, b, precision=HIGHEST)


def convolve(a, v, mode="full"):
  """jnp.convolve in full float32 on every backend (metrics)."""
  return jnp.convolve(a, v, mode=mode, precision=HIGHEST)


def network_precision(name):
  """The jax precision of model.matmul_precision `name` ('default', 'high', 'highest')."""
  if name not in NETWORK_PRECISIONS:
    raise ValueError(f"model.matmul_precision {name!r} is not one of "
                     f"{', '.join(NETWORK_PRECISIONS)}")
  return NETWORK_PRECISIONS[name]


def emulated():
  """The emulations installed in this process (a set of names from EMULATIONS)."""
  return set(_installed)


def emulate(*names):
  """Install the CPU emulations `names` ('tf32', 'div'; see the module doc). Idempotent."""
  for name in names:
    if name not in EMULATIONS:
      raise ValueError(f"{ENVIRONMENT}: {name!r} is not one of {', '.join(EMULATIONS)}")
    if name not in _installed:
      {"tf32": _emulate_tf32, "div": _emulate_division}[name]()
      _installed.add(name)


def _full_float32(precision):
  """Whether a dot_general or convolution `precision` parameter asks for full float32."""
  if precision is None:
    default = jax.config.jax_default_matmul_precision
    return default is not None and str(default).lower() in ("highest", "float32")
  precisions = precision if isinstance(precision, tuple) else (precision,)
  return all(p == HIGHEST or str(p).lower() in ("highest", "float32") for p in precisions)


def _rounded_inputs(ctx, operands, precision):
  """The float32 operands rounded to TF32 unless `precision` asks for full float32."""
  # pylint: disable=import-outside-toplevel
  from jax._src.interpreters import mlir
  if _full_float32(precision):
    return operands
  to_tf32 = mlir.lower_fun(lambda x: jax.lax.reduce_precision(x, 8, 10), multiple_results=False)
  out = []
  for aval, operand in zip(ctx.avals_in, operands):
    if aval.dtype == np.float32:
      operand = to_tf32(ctx.replace(avals_in=[aval], avals_out=[aval]), operand)[0]
    out.append(operand)
  return out


def _emulate_tf32():
  # pylint: disable=import-outside-toplevel
  from jax._src.interpreters import mlir
  from jax._src.lax import convolution, lax as lax_internal
  for prim in (lax_internal.dot_general_p, convolution.conv_general_dilated_p):
    rule = _cpu_rule(prim)

    def emulated_rule(ctx, lhs, rhs, *, precision, _rule=rule, **params):
      lhs, rhs = _rounded_inputs(ctx, (lhs, rhs), precision)
      return _rule(ctx, lhs, rhs, precision=precision, **params)
    mlir.register_lowering(prim, emulated_rule, platform="cpu")


def _emulate_division():
  # pylint: disable=import-outside-toplevel
  from jax._src.interpreters import mlir
  from jax._src.lax import lax as lax_internal
  rule = _cpu_rule(lax_internal.div_p)

  def approximate(x, y):
    # x·rcp(y), as a GPU's approximate division: the reciprocal is exact for a power of two
    # (so x/1 = x) and otherwise one ulp larger in magnitude than the rounded 1/y; the product
    # rounds once more, up to 3.3 ulps in all (x/x can be 1 + 2^-23). integer_pow(y, -1) lowers
    # to its own divide, not to div_p: no recursion into this rule.
    r = jax.lax.integer_pow(y, -1)
    bits = jax.lax.bitcast_convert_type(y, jnp.int32)
    # Adding 1 to the bits of a finite nonzero float grows its magnitude by one ulp.
    bumped = jax.lax.bitcast_convert_type(jax.lax.bitcast_convert_type(r, jnp.int32) + 1,
                                          jnp.float32)
    inexact = ((bits & 0x7FFFFF) != 0) & jnp.isfinite(bumped) & (r != 0)
    return x * jnp.where(inexact, bumped, r)
  lowered = mlir.lower_fun(approximate, multiple_results=False)

  def emulated_rule(ctx, x, y, **params):
    if ctx.avals_out[0].dtype != np.float32:
      return rule(ctx, x, y, **params)
    return lowered(ctx, x, y)
  mlir.register_lowering(lax_internal.div_p, emulated_rule, platform="cpu")


def _cpu_rule(prim):
  """The lowering rule XLA's CPU backend uses today for `prim`."""
  # pylint: disable=import-outside-toplevel,protected-access
  from jax._src.interpreters import mlir
  entry = mlir._platform_specific_lowerings["cpu"].get(prim) or mlir._lowerings[prim]
  return entry.rule


def _from_environment():
  names = [n.strip() for n in os.environ.get(ENVIRONMENT, "").split(",") if n.strip()]
  try:
    emulate(*names)
  except (AttributeError, ImportError, KeyError, TypeError) as e:  # jax's internals moved
    warnings.warn(f"{ENVIRONMENT}={','.join(names)}: the emulation needs jax internals this "
                  f"jax {jax.__version__} lacks ({e!r}); running without it")


_from_environment()
