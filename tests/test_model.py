"""The Flax MLP: shapes, the skip connection, view dependence and precision."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.model import NerfMLP


def _init(model, pos_dim=9, dir_dim=9, key=0):
  pos = jnp.zeros((1, pos_dim))
  return model.init(jax.random.PRNGKey(key), pos, jnp.zeros((1, dir_dim)))["params"]


def test_shapes_and_ranges():
  model = NerfMLP(depth=4, width=16, skip_layers=(2,))
  params = _init(model)
  x = jax.random.normal(jax.random.PRNGKey(1), (5, 7, 9))
  rgb, raw = model.apply({"params": params}, x)
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
  rgb1, s1 = model.apply({"params": params}, pos, d1)
  rgb2, s2 = model.apply({"params": params}, pos, d2)
  np.testing.assert_array_equal(s1, s2)  # density never sees the direction
  assert np.max(np.abs(rgb1 - rgb2)) > 1e-4
  # With the direction weights of the view layer zeroed, colour no longer depends on direction.
  kernel = params["view"]["kernel"]
  zeroed = jax.tree_util.tree_map(lambda x: x, params)
  zeroed["view"]["kernel"] = kernel.at[16:].set(0.0)
  rgb1, _ = model.apply({"params": zeroed}, pos, d1)
  rgb2, _ = model.apply({"params": zeroed}, pos, d2)
  np.testing.assert_allclose(rgb1, rgb2, atol=1e-7)


@pytest.mark.parametrize("dtype", ["bfloat16", "float16"])
def test_low_precision_matmuls_return_float32_close_to_float32(dtype):
  x = jax.random.normal(jax.random.PRNGKey(4), (64, 9))
  ref = NerfMLP(depth=3, width=32, skip_layers=(1,))
  low = NerfMLP(depth=3, width=32, skip_layers=(1,), dtype=dtype)
  params = _init(ref)
  rgb32, s32 = ref.apply({"params": params}, x)
  rgb, s = low.apply({"params": params}, x)
  assert rgb.dtype == jnp.float32 and s.dtype == jnp.float32
  assert jax.tree_util.tree_leaves(params)[0].dtype == jnp.float32
  tol = 3e-2 if dtype == "bfloat16" else 5e-3
  np.testing.assert_allclose(rgb, rgb32, atol=tol)
  np.testing.assert_allclose(s, s32, atol=tol * (1 + np.max(np.abs(s32))))
