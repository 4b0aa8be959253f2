"""The Flax MLP: shapes, the skip connection, view dependence and precision."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.fields.networks import mlp
from nerf_jax.fields.protocol import NetworkSettings
from tests.helpers import NETWORK_RTOL, jitted


def NerfMLP(depth, width, skip_layers=(4,), **shared):  # pylint: disable=invalid-name
  """mlp.NerfMLP of `depth` layers of `width` (shared: further NetworkSettings fields)."""
  return mlp.NerfMLP(mlp.Settings(depth, skip_layers), NetworkSettings(width=width, **shared))


def _init(model, pos_dim=9, dir_dim=9, key=0):
  pos = jnp.zeros((1, pos_dim))
  return jitted(model.init)(jax.random.PRNGKey(key), pos, jnp.zeros((1, dir_dim)))["params"]


def test_shapes_and_ranges():
  model = NerfMLP(depth=4, width=16, skip_layers=(2,))
  params = _init(model)
  x = jax.random.normal(jax.random.PRNGKey(1), (5, 7, 9))
  rgb, raw = jitted(model.apply)({"params": params}, x)
  assert rgb.shape == (5, 7, 3) and raw.shape == (5, 7)
  assert np.all((rgb > 0) & (rgb < 1))


def test_skip_layer_widens_the_next_layer():
  params = _init(NerfMLP(depth=4, width=16, skip_layers=(1,)), pos_dim=9)
  assert params["layer_2"]["kernel"].shape == (16 + 9, 16)
  assert params["layer_1"]["kernel"].shape == (16, 16)


def test_view_branch_makes_colour_depend_on_direction_only():
  model = NerfMLP(depth=3, width=16, skip_layers=(), view_dependent=True, view_width=8)
  params = _init(model)
  pos = jax.random.normal(jax.random.PRNGKey(2), (4, 9))
  d1, d2 = jax.random.normal(jax.random.PRNGKey(3), (2, 4, 9))
  apply = jitted(model.apply)
  rgb1, s1 = apply({"params": params}, pos, d1)
  rgb2, s2 = apply({"params": params}, pos, d2)
  np.testing.assert_array_equal(s1, s2)  # density never sees the direction
  assert np.max(np.abs(rgb1 - rgb2)) > 1e-4
  # With the direction weights of the view layer zeroed, colour no longer depends on direction.
  kernel = params["view"]["kernel"]
  zeroed = jax.tree_util.tree_map(lambda x: x, params)
  zeroed["view"]["kernel"] = kernel.at[16:].set(0.0)
  rgb1, _ = apply({"params": zeroed}, pos, d1)
  rgb2, _ = apply({"params": zeroed}, pos, d2)
  np.testing.assert_allclose(rgb1, rgb2, atol=1e-7)


@pytest.mark.parametrize("dtype", ["bfloat16", "float16"])
def test_low_precision_matmuls_return_float32_close_to_float32(dtype):
  x = jax.random.normal(jax.random.PRNGKey(4), (64, 9))
  ref = NerfMLP(depth=3, width=32, skip_layers=(1,))
  low = NerfMLP(depth=3, width=32, skip_layers=(1,), dtype=dtype)
  params = _init(ref)
  rgb32, s32 = jitted(ref.apply)({"params": params}, x)
  rgb, s = jitted(low.apply)({"params": params}, x)
  assert rgb.dtype == jnp.float32 and s.dtype == jnp.float32
  assert jax.tree_util.tree_leaves(params)[0].dtype == jnp.float32
  tol = 3e-2 if dtype == "bfloat16" else 5e-3
  np.testing.assert_allclose(rgb, rgb32, atol=tol)
  np.testing.assert_allclose(s, s32, atol=tol * (1 + np.max(np.abs(s32))))


def _reference_mlp(params, pos, dirs=None, skip_layers=()):
  """NerfMLP's forward pass in NumPy (float64): ReLU layers, after a skip layer the layer's
  output followed by the input ([h, x], in that order), a 4-output head or the view branch."""
  dense = lambda name, h: h @ np.asarray(params[name]["kernel"], np.float64) + np.asarray(
      params[name]["bias"], np.float64)
  sigmoid = lambda z: 1.0 / (1.0 + np.exp(-z))
  x = h = np.asarray(pos, np.float64)
  i = 0
  while f"layer_{i}" in params:
    h = np.maximum(dense(f"layer_{i}", h), 0.0)
    if i in skip_layers:
      h = np.concatenate([h, x], -1)
    i += 1
  if dirs is None:
    out = dense("output", h)
    return sigmoid(out[..., :3]), out[..., 3]
  sigma = dense("sigma", h)[..., 0]
  h = np.concatenate([dense("feature", h), np.asarray(dirs, np.float64)], -1)
  h = np.maximum(dense("view", h), 0.0)
  j = 1
  while f"view_{j}" in params:  # the colour branch's further layers (view_depth > 1)
    h = np.maximum(dense(f"view_{j}", h), 0.0)
    j += 1
  return sigmoid(dense("rgb", h)), sigma


@pytest.mark.parametrize("view_dependent, view_depth", [(False, 1), (True, 1), (True, 3)])
def test_forward_pass_matches_a_numpy_reference(view_dependent, view_depth):
  # Full float32 matmuls: the wiring is checked to float32 rounding on every backend.
  model = NerfMLP(depth=4, width=16, skip_layers=(1,), view_dependent=view_dependent,
                  view_width=8, view_depth=view_depth, matmul_precision="highest")
  params = _init(model, key=5)
  views = sorted(name for name in params if name.startswith("view"))
  assert views == (["view", "view_1", "view_2"][:view_depth] if view_dependent else [])
  # Random biases too (Flax starts them at zero, which would hide a bias left out).
  leaves, tree = jax.tree_util.tree_flatten(params)
  keys = jax.random.split(jax.random.PRNGKey(6), len(leaves))
  params = jax.tree_util.tree_unflatten(tree, [x + 0.3 * jax.random.normal(k, x.shape)
                                               for x, k in zip(leaves, keys)])
  pos, dirs = jax.random.normal(jax.random.PRNGKey(7), (2, 11, 9))
  dirs = dirs if view_dependent else None
  rgb, sigma = jitted(model.apply)({"params": params}, pos, dirs)
  ref_rgb, ref_sigma = _reference_mlp(params, pos, dirs, (1,))
  np.testing.assert_allclose(rgb, ref_rgb, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(sigma, ref_sigma, rtol=1e-5, atol=1e-5)
  # At the backend's default precision (TF32 on GPUs, emulated on the CPU by the tests), the
  # same network within the TF32 tolerance, stated once for every network test.
  default = model.clone(shared=dataclasses.replace(model.shared, matmul_precision="default"))
  rgb, sigma = jitted(default.apply)({"params": params}, pos, dirs)
  np.testing.assert_allclose(rgb, ref_rgb, rtol=NETWORK_RTOL, atol=NETWORK_RTOL)
  np.testing.assert_allclose(sigma, ref_sigma, rtol=NETWORK_RTOL, atol=NETWORK_RTOL)


def test_a_colour_branch_without_layers_is_a_one_line_error():
  with pytest.raises(ValueError, match="config.model.view_depth must be >= 1"):
    _init(NerfMLP(depth=2, width=8, view_dependent=True, view_depth=0))
