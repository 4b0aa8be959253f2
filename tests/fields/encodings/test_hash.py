"""Hash-grid encoding: the hash and the row indices against Python-integer brute force, dense
levels against grid.trilinear, exact linear interpolation, the gradient's support, float16,
fitting a 3D function with Adam, and one step of the hash grid and the lattice head through the
real renderer."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from nerf_jax.fields.encodings import grid
from nerf_jax.fields.encodings import hash as hashgrid
from nerf_jax.run import builders
from nerf_jax.run.signature import model_signature
from nerf_jax.fields.networks.lattice import LatticeHead
from nerf_jax.fields.protocol import NetworkSettings
from tests.helpers import grey_view_loss, ray_renderer, small_config

P1, P2 = 2654435761, 805459861


def _hash_brute(x, y, z, log2_size):
  """instant-ngp's hash with Python's unbounded integers, reduced modulo 2^32 by hand."""
  return ((x * 1) ^ (y * P1) ^ (z * P2)) % 2 ** 32 % 2 ** log2_size


def _rows_brute(u, resolutions, log2_size):
  """Per level: the 8 (row, weight) pairs of unit position u, from the definitions."""
  out, offset = [], 0
  for res in resolutions:
    x = [min(max(float(c), 0.0), 1.0) * (res - 1) for c in u]
    lower = [min(int(np.floor(v)), res - 2) for v in x]
    dense = res ** 3 <= 2 ** log2_size
    level = []
    for corner in itertools.product([0, 1], repeat=3):
      i, j, k = (lower[a] + corner[a] for a in range(3))
      row = (i * res + j) * res + k if dense else _hash_brute(i, j, k, log2_size)
      weight = np.prod([1 - abs(x[a] - lower[a] - corner[a]) for a in range(3)])
      level.append((offset + row, weight))
    out.append(level)
    offset += min(res ** 3, 2 ** log2_size)
  return out


@pytest.mark.parametrize("log2_size", [4, 19, 24])
def test_spatial_hash_matches_python_integers(log2_size):
  rng = np.random.default_rng(log2_size)
  corners = rng.integers(0, 2 ** 20, (200, 3))  # products far beyond 2^32: they must wrap
  corners[0] = [2 ** 20 - 1] * 3
  corners[1] = [0, 0, 0]
  got = np.asarray(hashgrid.spatial_hash(jnp.asarray(corners, jnp.int32), log2_size))
  want = [_hash_brute(int(x), int(y), int(z), log2_size) for x, y, z in corners]
  np.testing.assert_array_equal(got, want)


def test_corner_rows_and_weights_match_brute_force():
  resolutions = hashgrid.level_resolutions(5, 4, 300)  # dense up to 16^3 = 2^12, then hashed
  log2_size = 12
  rng = np.random.default_rng(1)
  u = rng.random((20, 3)).astype(np.float32)
  u[0], u[1] = [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]  # box corners: floor clamped to R - 2
  u[2] = [-0.2, 0.5, 1.3]  # outside: clamped to the surface
  rows, weights = hashgrid.corner_rows(jnp.asarray(u), resolutions, log2_size)
  assert rows.shape == (20, 5, 8) and weights.shape == (20, 5, 8)
  for p in range(len(u)):
    for level, pairs in enumerate(_rows_brute(u[p], resolutions, log2_size)):
      np.testing.assert_array_equal(rows[p, level], [r for r, _ in pairs])
      # float32 u·(R - 1) < 300 is rounded by up to ulp(300) / 2 = 1.5e-5 (float64 here).
      np.testing.assert_allclose(weights[p, level], [w for _, w in pairs], atol=3e-5)


def test_dense_levels_give_what_grid_trilinear_gives():
  resolutions, log2_size, f = (4, 7, 16), 12, 3  # 16^3 = 2^12 rows: every level dense
  rows = hashgrid.level_rows(resolutions, log2_size)
  assert rows == (64, 343, 4096)
  table = jax.random.normal(jax.random.PRNGKey(0), (sum(rows), f))
  u = jax.random.uniform(jax.random.PRNGKey(1), (64, 3), minval=-0.1, maxval=1.1)
  got = jax.jit(hashgrid.encode, static_argnums=(2, 3))(table, u, resolutions, log2_size)
  offset = 0
  for level, res in enumerate(resolutions):
    g = table[offset:offset + res ** 3].reshape(res, res, res, f)
    np.testing.assert_allclose(got[:, level * f:(level + 1) * f], jax.jit(grid.trilinear)(g, u),
                               rtol=0, atol=2e-6)
    offset += res ** 3


def test_interpolation_reproduces_a_linear_function_on_a_dense_level():
  res = 9
  i, j, k = np.meshgrid(*[np.arange(res)] * 3, indexing="ij")
  lattice = np.stack([i, j, k], -1).reshape(-1, 3) / (res - 1)  # row (i·R + j)·R + k
  a, b = np.array([[0.7, -1.3], [2.0, 0.5], [-0.4, 1.1]]), np.array([0.25, -0.5])
  table = jnp.asarray(lattice @ a + b, jnp.float32)  # f(p) = p·a + b at every lattice point
  u = jax.random.uniform(jax.random.PRNGKey(2), (100, 3))
  got = hashgrid.encode(table, u, (res,), 10)
  np.testing.assert_allclose(got, np.asarray(u) @ a + b, rtol=0, atol=2e-6)


def test_gradient_of_one_lookup_touches_exactly_the_8_corner_rows_per_level():
  resolutions = hashgrid.level_resolutions(4, 4, 200)  # 4, 8, 28 dense; 200 hashed
  log2_size = 15
  u = jnp.array([[0.3141, 0.5926, 0.5358]])  # inside a cell of every level: 8 weights > 0
  table = jnp.zeros((sum(hashgrid.level_rows(resolutions, log2_size)), 2))
  grad = jax.grad(lambda t: jnp.sum(hashgrid.encode(t, u, resolutions, log2_size)))(table)
  touched = {int(r): float(g) for r, g in enumerate(np.asarray(grad[:, 0])) if g != 0}
  want = {row: w for level in _rows_brute(np.asarray(u[0]), resolutions, log2_size)
          for row, w in level}
  assert len(want) == 8 * len(resolutions)  # no two corners of a level share a row here
  assert set(touched) == set(want)
  np.testing.assert_allclose([touched[r] for r in sorted(want)], [want[r] for r in sorted(want)],
                             atol=2e-5)  # d(sum)/d(row): the weight (float32 u·199 vs float64)
  np.testing.assert_array_equal(grad[:, 0], grad[:, 1])


def test_level_resolutions_span_base_to_max_geometrically():
  res = hashgrid.level_resolutions(16, 16, 2048)
  assert len(res) == 16 and res[0] == 16 and res[-1] == 2048
  growth = (2048 / 16) ** (1 / 15)
  for level, r in enumerate(res):
    assert abs(r - 16 * growth ** level) <= 0.5  # rounded from the geometric progression
  assert hashgrid.level_resolutions(1, 16, 16) == (16,)
  rows = hashgrid.level_rows(res, 19)
  assert rows[:5] == tuple(r ** 3 for r in res[:5]) and set(rows[5:]) == {2 ** 19}
  with pytest.raises(ValueError, match="model.hash.max_resolution"):
    hashgrid.level_resolutions(4, 64, 32)
  with pytest.raises(ValueError, match="model.hash.log2_size"):
    hashgrid.level_rows(res, 30)


def _small_model(gather_dtype="float32"):
  settings = hashgrid.Settings(levels=4, log2_size=10, features=2, base_resolution=4,
                               max_resolution=64, gather_dtype=gather_dtype)
  return LatticeHead(hashgrid.HashGrid(settings, grid.Space(1.0)), NetworkSettings(width=16))


def test_float16_rows_give_finite_values_and_gradients_close_to_float32():
  points = jax.random.uniform(jax.random.PRNGKey(3), (512, 3), minval=-1.0, maxval=1.0)
  target = jax.random.uniform(jax.random.PRNGKey(4), (512, 3))
  params = _small_model().init(jax.random.PRNGKey(5), points)["params"]
  # A "trained" table: at the ±1e-4 initial scale the hidden layer's pre-activations are ~1e-5,
  # and float16's rounding of the features flips ReLU gates, which is not what is tested here.
  table_shape = params["hash_table"].shape
  params["hash_table"] = 0.1 * jax.random.normal(jax.random.PRNGKey(6), table_shape)
  grads = {}
  for dtype in ("float32", "float16"):
    model = _small_model(gather_dtype=dtype)
    rgb, sigma = jax.jit(model.apply)({"params": params}, points)
    assert rgb.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(rgb)))
    assert bool(jnp.all(jnp.isfinite(sigma)))
    loss = lambda p: jnp.mean((model.apply({"params": p}, points)[0] - target) ** 2)
    grads[dtype] = jax.jit(jax.grad(loss))(params)["hash_table"]
  g16, g32 = grads["float16"], grads["float32"]
  assert g16.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(g16)))
  assert params["hash_table"].dtype == jnp.float32  # Adam sees float32 parameters
  # The cotangents (1e-5 to 1e-8 here, a mean over 512 points) would be subnormal in float16;
  # the gradient is computed in float32 and differs only through float16's rounding of the
  # features (relative 2^-11). Plain autodiff through the casts zeroes ~1% of these entries.
  np.testing.assert_array_equal(g16 != 0, g32 != 0)
  assert int(jnp.sum(g32 != 0)) > 1000
  assert float(jnp.linalg.norm(g16 - g32) / jnp.linalg.norm(g32)) < 1e-2


def test_adam_fits_a_3d_function_through_the_encoding_and_a_linear_layer():
  resolutions = hashgrid.level_resolutions(4, 4, 48)  # 4, 10, 22 dense; 48 hashed into 2^12
  log2_size, f = 12, 2
  target = lambda u: jnp.sin(2 * jnp.pi * u[..., 0]) * jnp.cos(2 * jnp.pi * u[..., 1]) + u[..., 2]
  table_rows = sum(hashgrid.level_rows(resolutions, log2_size))
  k1, k2 = jax.random.split(jax.random.PRNGKey(6))
  params = {"table": jax.random.uniform(k1, (table_rows, f), minval=-1e-4, maxval=1e-4),
            "w": 0.5 * jax.random.normal(k2, (len(resolutions) * f,)), "b": jnp.zeros(())}
  predict = lambda p, u: hashgrid.encode(p["table"], u, resolutions, log2_size) @ p["w"] + p["b"]
  tx = optax.adam(1e-2)

  @jax.jit
  def step(params, opt_state, key):
    u = jax.random.uniform(key, (1024, 3))
    grads = jax.grad(lambda p: jnp.mean((predict(p, u) - target(u)) ** 2))(params)
    updates, opt_state = tx.update(grads, opt_state)
    return optax.apply_updates(params, updates), opt_state

  opt_state = tx.init(params)
  for i in range(300):
    params, opt_state = step(params, opt_state, jax.random.PRNGKey(100 + i))
  u = jax.random.uniform(jax.random.PRNGKey(7), (4096, 3))  # held-out points
  rmse = float(jnp.sqrt(jnp.mean((predict(params, u) - target(u)) ** 2)))
  # std of the target is 0.60; trilinear interpolation on the 22^3 level alone errs by ~0.01;
  # measured 0.016 after 300 steps.
  assert rmse < 0.05, rmse


HASH_DEBUG = {"model.encoding": "hash", "model.hash.levels": 4, "model.hash.log2_size": 10,
              "model.hash.base_resolution": 4, "model.hash.max_resolution": 64,
              "model.density_activation": "softplus", "data.scene_bound": 1.5}


def test_hash_model_trains_one_step_through_the_ray_renderer():
  rr = ray_renderer(small_config(HASH_DEBUG))
  assert isinstance(rr.field.network.encoding, hashgrid.HashGrid)
  params = rr.init(jax.random.PRNGKey(0))["params"]
  table = params["coarse"]["hash_table"]
  assert table.shape == (4 ** 3 + 10 ** 3 + 2 * 2 ** 10, 2)  # 4, 10 dense; 25, 64 hashed
  assert float(jnp.max(jnp.abs(table))) <= 1e-4  # instant-ngp's initial scale
  tx = optax.adam(1e-2)
  loss_and_grad = jax.jit(jax.value_and_grad(grey_view_loss(rr)))
  loss, grads = loss_and_grad(params)
  updates, _ = tx.update(grads, tx.init(params))
  new_params = optax.apply_updates(params, updates)
  assert np.isfinite(float(loss)) and np.isfinite(float(loss_and_grad(new_params)[0]))
  g = grads["coarse"]["hash_table"]
  assert bool(jnp.all(jnp.isfinite(g))) and int(jnp.sum(jnp.any(g != 0, axis=-1))) > 100
  assert float(jnp.max(jnp.abs(new_params["coarse"]["hash_table"] - table))) > 1e-3


def test_config_signature_and_errors():
  config = small_config(base="hash")
  network = builders.make_field(config).network  # the hash grid read by the lattice head
  assert isinstance(network, LatticeHead) and isinstance(network.encoding, hashgrid.HashGrid)
  signature = model_signature(config)
  assert signature["hash_log2_size"] == config.model.hash.log2_size
  assert signature["hash_max_resolution"] == config.model.hash.max_resolution
  settings = network.encoding.settings
  assert settings.max_resolution == 2048 and settings.log2_size == config.model.hash.log2_size
  points = jnp.array([[0.0, 0.0, 0.0], [1.2, 0.0, 0.0]])  # inside, outside the box (bound 1)
  small = _small_model()
  _, raw_sigma = small.apply({"params": small.init(jax.random.PRNGKey(0), points)["params"]},
                             points)
  assert float(raw_sigma[0]) > -1e4 and float(raw_sigma[1]) == -1e5
  config.model.encoding = "hashgrid"
  with pytest.raises(ValueError, match="config.model.encoding"):
    builders.make_field(config)
  with pytest.raises(ValueError, match="model.hash.gather_dtype"):
    hashgrid.encode(jnp.zeros((64, 1)), jnp.zeros((1, 3)), (4,), 6, "float64")
  config.model.encoding = "hash"  # validated where the settings are built, naming the field
  config.model.hash.gather_dtype = "float64"
  with pytest.raises(ValueError, match="model.hash.gather_dtype must be one of"):
    builders.make_field(config)


# Unit roundoff u of round-to-nearest: bfloat16 keeps 8 significant bits (7 stored), float16 11
# (10 stored), so a rounded value errs by at most u = 2^-8 or 2^-11 of itself.
UNIT_ROUNDOFF = {"bfloat16": 2.0 ** -8, "float16": 2.0 ** -11}


@pytest.mark.parametrize("dtype", sorted(UNIT_ROUNDOFF))
def test_low_precision_gather_is_within_its_rounding_of_float32(dtype):
  """model.hash.gather_dtype against float32, values and the table's gradient.

  Values: each feature is sum_c w_c·row_c over a level's 8 corners, with the rows and weights
  rounded to `dtype` (2 roundings), each product (1) and each of the 7 additions (7): by the
  classic bound for a dot product, |low - f32| <= g_10 · sum_c w_c·|row_c|, g_n = n·u / (1 - n·u),
  and sum_c w_c·|row_c| is the float32 encoding of |table| (w >= 0).
  Gradient: computed in float32 from the float32 rows (`_interpolate_low`), so only the
  cotangent differs: for 0.5·sum((features - target)^2) / N it carries the features' error,
  |Δg| <= bound / N, and the table's gradient (a scatter-add of w·g) moves by at most the
  float32 gradient of the cotangent bound / N; plus float32's own rounding of the sums (2^-20
  of the sum of |w·g|, far above its 2^-24 per addition for these few hits per row).
  """
  resolutions = hashgrid.level_resolutions(4, 4, 64)  # 4, 10 dense; 25, 64 hashed into 2^10
  log2_size = 10
  rows = sum(hashgrid.level_rows(resolutions, log2_size))
  k1, k2, k3 = jax.random.split(jax.random.PRNGKey(11), 3)
  table = 0.1 * jax.random.normal(k1, (rows, 2))  # a trained table's scale, not the 1e-4 init
  unit = jax.random.uniform(k2, (512, 3))
  target = jax.random.normal(k3, (512, len(resolutions) * 2))
  encode = lambda t, dt: hashgrid.encode(t, unit, resolutions, log2_size, dt)
  n = 10 * UNIT_ROUNDOFF[dtype]
  bound = n / (1 - n) * encode(jnp.abs(table), "float32")  # float32 [512, L·F]
  low, f32 = encode(table, dtype), encode(table, "float32")
  assert low.dtype == jnp.float32
  error = jnp.abs(low - f32)
  assert bool(jnp.all(error <= bound)), float(jnp.max(error / bound))
  assert float(jnp.max(error)) > 0  # the rows really were rounded to `dtype`

  loss = lambda t, dt: 0.5 * jnp.sum((encode(t, dt) - target) ** 2) / len(unit)
  g_low, g32 = jax.grad(loss)(table, dtype), jax.grad(loss)(table, "float32")
  _, pull = jax.vjp(lambda t: encode(t, "float32"), table)
  moved = pull(bound / len(unit))[0]  # float32 [rows, F]: the gradient's error bound
  scale = pull(jnp.abs(encode(table, "float32") - target) / len(unit))[0]  # sum of |w·g|
  assert bool(jnp.all(jnp.abs(g_low - g32) <= moved + 2.0 ** -20 * scale))
  np.testing.assert_array_equal(g_low != 0, g32 != 0)  # no gradient flushed to zero
