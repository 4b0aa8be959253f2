"""The numerics catalogue (docs/numerics.md, issue 2): hard cases stay finite and exact.

Each test is one case of the catalogue. Where naive code fails, a few lines of the naive
formulation sit next to the check and show the failure (NaN, a leak, a zero). jax_debug_nans is on
for the whole module, so any NaN produced by the library, even in a discarded `where` branch or in a
backward pass, fails the test; a naive formulation's NaN shows up as FloatingPointError.

Speed: data are made with numpy, and the library is called through a few jitted functions shared
by the cases (one compilation per shape), not op by op.
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax import rendering
from nerf_jax.cameras import rays
from nerf_jax.fields import activations
from nerf_jax.fields.encodings import posenc
from nerf_jax.samplers import spacing
from nerf_jax.volume import quadrature

LOW_PRECISION = [jnp.bfloat16, jnp.float16]
# Unit roundoff u of each low-precision dtype (half its machine epsilon).
UNIT_ROUNDOFF = {jnp.bfloat16: 2.0 ** -8, jnp.float16: 2.0 ** -11}


pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: NaNs raise in this module


def _assert_finite(*trees):
  for leaf in jax.tree_util.tree_leaves(trees):
    assert np.all(np.isfinite(np.asarray(leaf, np.float64))), leaf


def _numpy(tree):
  return jax.tree_util.tree_map(np.asarray, tree)


def _render_loss(rgb, sigma, t, background):
  """A scalar touching every output, so its gradient exercises every backward path."""
  out = rendering.composite(rgb, sigma, t, background)
  return (jnp.sum(out["rgb"]) + jnp.sum(out["depth"]) + jnp.sum(out["acc"])
          + jnp.sum(out["weights"]))


def _sum_acc(rgb, sigma, t, background):
  return jnp.sum(rendering.composite(rgb, sigma, t, background)["acc"])


@jax.jit
def _composite_and_grads(rgb, sigma, t, background):
  """composite's outputs; gradients of `_render_loss` wrt (rgb, sigma, t); d sum(acc) / d sigma."""
  return (rendering.composite(rgb, sigma, t, background),
          jax.grad(_render_loss, argnums=(0, 1, 2))(rgb, sigma, t, background),
          jax.grad(_sum_acc, argnums=1)(rgb, sigma, t, background))


def _colour(rgb, sigma, t, background):
  return rendering.composite(rgb, sigma, t, background)["rgb"]


# Jacobians of one ray's colour [3] with respect to its rgb [S, 3] and sigma [S].
_colour_jacobians = jax.jit(jax.jacobian(_colour, argnums=(0, 1)))
_stratified = jax.jit(spacing.stratified, static_argnums=(2, 3, 5))
_sample_pdf = jax.jit(spacing.sample_pdf, static_argnums=(2,))


def _edges(deltas, start=0.0):
  """Interval edges float32 [..., S + 1] from widths float [..., S]."""
  deltas = np.asarray(deltas, np.float64)
  zeros = np.zeros(deltas.shape[:-1] + (1,))
  return (start + np.concatenate([zeros, np.cumsum(deltas, axis=-1)], axis=-1)).astype(np.float32)


@jax.jit
def _naive_weights(sigma, t):
  """The original NeRF formulation: cumprod(1 - alpha + 1e-10) transmittance, 1 - exp(-tau)."""
  alpha = 1.0 - jnp.exp(-sigma * (t[..., 1:] - t[..., :-1]))
  trans = jnp.cumprod(1.0 - alpha + 1e-10, axis=-1)
  trans = jnp.concatenate([jnp.ones_like(trans[..., :1]), trans[..., :-1]], axis=-1)
  return alpha * trans


def _reference_composite(rgb, sigma, t, background):
  """Brute-force float64 loop over one ray: T_i = prod_{j<i} exp(-tau_j), w_i = T_i (1 - e^-tau_i).

  Returns weights [S], colour [3], the transmittance left T_S, and the depth (far if empty).
  """
  rgb, sigma, t = (np.asarray(a, np.float64) for a in (rgb, sigma, t))
  weights, trans = np.zeros(len(sigma)), 1.0
  for i in range(len(sigma)):
    tau = sigma[i] * (t[i + 1] - t[i])
    weights[i] = trans * -math.expm1(-tau)
    trans *= math.exp(-tau)
  colour = weights @ rgb + trans * np.asarray(background, np.float64)
  depth = weights @ (0.5 * (t[1:] + t[:-1])) / weights.sum() if weights.sum() > 0 else t[-1]
  return weights, colour, trans, depth


BACKGROUND = np.array([0.3, 0.6, 0.9], np.float32)


# --- 1. An opaque sample followed by more samples -----------------------------------------------

def test_case01_opaque_sample_blocks_everything_behind_it():
  num, opaque = 16, 5
  rng = np.random.default_rng(1)
  sigma = rng.uniform(0.1, 2.0, num).astype(np.float32)
  sigma[opaque] = 1e10
  t = _edges(rng.uniform(0.05, 0.2, num), start=2.0)
  rgb = rng.uniform(size=(num, 3)).astype(np.float32)

  out, grads, grad_acc = _numpy(_composite_and_grads(rgb, sigma, t, BACKGROUND))
  _assert_finite(out, grads, grad_acc)
  np.testing.assert_array_equal(out["weights"][opaque + 1:], 0.0)  # exactly, not 1e-10-ish
  np.testing.assert_array_equal(out["acc"], 1.0)

  # Gradients against the analytic values (float64 loop):
  #   d rgb / d c_i = w_i;  d rgb / d sigma_i = delta_i (T_{i+1} c_i - sum_{j>i} w_j c_j - T_S bg);
  #   d acc / d sigma_i = delta_i exp(-sum tau) = 0 here.
  weights, _, trans_end, _ = _reference_composite(rgb, sigma, t, BACKGROUND)
  jac_rgb, jac_sigma = _numpy(_colour_jacobians(rgb, sigma, t, BACKGROUND))
  np.testing.assert_allclose(jac_rgb[0, :, 0], weights, rtol=1e-6, atol=1e-7)
  delta = np.diff(t.astype(np.float64))
  trans_after = np.exp(-np.cumsum(sigma * delta))
  c = rgb.astype(np.float64)
  expected = np.stack([delta[i] * (trans_after[i] * c[i] - weights[i + 1:] @ c[i + 1:]
                                   - trans_end * BACKGROUND) for i in range(num)], axis=-1)
  np.testing.assert_allclose(jac_sigma, expected, rtol=1e-5, atol=1e-7)
  np.testing.assert_array_equal(jac_sigma[:, opaque + 1:], 0.0)
  np.testing.assert_array_equal(grad_acc, 0.0)

  # Naive: the 1e-10 in cumprod(1 - alpha + 1e-10) leaks light through the opaque sample (as
  # written, here in numpy; XLA may reassociate the sum and hide or change the leak).
  alpha = 1.0 - np.exp(-sigma * np.diff(t))
  trans = np.cumprod(np.concatenate([[1.0], 1.0 - alpha[:-1] + 1e-10]).astype(np.float32))
  assert np.all((alpha * trans)[opaque + 1:] > 0)


# --- 2. All densities zero ----------------------------------------------------------------------

@jax.jit
def _naive_depth(weights, t):
  return jnp.sum(weights * 0.5 * (t[1:] + t[:-1])) / jnp.sum(weights)


def test_case02_empty_ray():
  num = 16
  t = _edges(np.full(num, 0.25), start=2.0)
  sigma = np.zeros(num, np.float32)
  rgb = np.random.default_rng(2).uniform(size=(num, 3)).astype(np.float32)
  out, grads, grad_acc = _numpy(_composite_and_grads(rgb, sigma, t, BACKGROUND))
  _assert_finite(out, grads, grad_acc)
  np.testing.assert_array_equal(out["rgb"], BACKGROUND)
  np.testing.assert_array_equal(out["acc"], 0.0)
  np.testing.assert_array_equal(out["depth"], t[-1])  # documented: an empty ray is at far
  # d acc / d sigma_i = delta_i exp(0) = delta_i; d rgb / d sigma_i = delta_i (c_i - bg).
  np.testing.assert_allclose(grad_acc, np.diff(t), rtol=1e-6)
  _, jac_sigma = _numpy(_colour_jacobians(rgb, sigma, t, BACKGROUND))
  np.testing.assert_allclose(jac_sigma, (np.diff(t)[:, None] * (rgb - BACKGROUND)).T,
                             rtol=1e-5, atol=1e-7)

  # Naive: depth = sum(w t) / sum(w) is 0/0.
  with pytest.raises(FloatingPointError):
    _naive_depth(_naive_weights(sigma, t), t)


# --- 3. Log-spaced grid of densities and distances -----------------------------------------------

def test_case03_log_spaced_density_and_distance_grid():
  grid = np.exp(np.linspace(-100.0, 10.0, 23))
  sig, dlt = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
  num = 8
  sigma = np.repeat(sig[:, None], num, axis=1).astype(np.float32)
  sigma[:, ::3] *= 0.5  # some variation along each ray
  t = _edges(np.repeat(dlt[:, None], num, axis=1))  # from t = 0: tiny widths stay resolvable
  rgb = np.random.default_rng(3).uniform(size=sigma.shape + (3,)).astype(np.float32)
  out, grads, grad_acc = _numpy(_composite_and_grads(rgb, sigma, t, BACKGROUND))
  _assert_finite(out, grads, grad_acc)
  assert np.all(out["weights"] >= 0)
  assert np.all((out["acc"] >= 0) & (out["acc"] <= 1))
  assert np.all((out["depth"] >= t[:, 0]) & (out["depth"] <= t[:, -1]))

  # Naive: the "infinite last interval" delta = 1e10 overflows float16 to inf, and a zero density
  # (relu of a negative raw value) times it is 0·inf = NaN.
  last = jnp.asarray(1e10, jnp.float32).astype(jnp.float16)
  assert np.isinf(last)
  with pytest.raises(FloatingPointError):
    jax.nn.relu(jnp.asarray(-1.0, jnp.float16)) * last


# --- 4. Random log-normal densities over 128 samples -----------------------------------------

def test_case04_random_lognormal_densities():
  rays_, num = 16, 128
  rng = np.random.default_rng(4)
  scale = np.logspace(-3, 1, rays_)[:, None]  # from nearly empty to opaque rays
  sigma = (scale * np.exp(rng.normal(0.0, 2.0, (rays_, num)))).astype(np.float32)
  t = _edges(rng.uniform(0.002, 0.04, (rays_, num)), start=2.0)
  rgb = rng.uniform(size=(rays_, num, 3)).astype(np.float32)
  out, grads, grad_acc = _numpy(_composite_and_grads(rgb, sigma, t, BACKGROUND))
  _assert_finite(out, grads, grad_acc)
  delta = np.diff(t.astype(np.float64), axis=-1)
  total = np.sum(sigma * delta, axis=-1)
  assert np.all(out["weights"] >= 0)
  assert np.all(out["acc"] <= 1 + 1e-6)
  np.testing.assert_allclose(out["acc"], -np.expm1(-total), rtol=0, atol=1e-6)
  # d acc / d sigma_i = delta_i exp(-sum sigma delta), to float32 rounding of the total.
  # (atol: float32 flushes results below its smallest normal number, 1.2e-38, to zero.)
  exact = delta * np.exp(-total)[:, None]
  np.testing.assert_allclose(grad_acc, exact, rtol=2e-5, atol=np.finfo(np.float32).tiny)

  # Naive: acc = sum(weights) differentiated by autodiff computes, in float32,
  # delta_i·(T_{i+1} - sum_{j>i} w_j), a cancellation: on opaque rays it is rounding noise of
  # ~1e-8·delta where the true value is ~exp(-total)·delta.
  weights = out["weights"]
  trans_after = np.exp(-np.cumsum(sigma * np.diff(t, axis=-1), axis=-1))  # float32 T_{i+1}
  behind = (np.sum(weights, -1, keepdims=True) - np.cumsum(weights, -1)).astype(np.float32)
  naive_grad = np.diff(t, axis=-1) * (trans_after - behind)
  opaque = total > 30
  assert np.any(opaque)
  assert np.max(np.abs(naive_grad[opaque] - exact[opaque]) / exact[opaque]) > 1.0


# --- 5. Tiny optical thickness ----------------------------------------------------------------

@pytest.mark.parametrize("dtype", [jnp.float32] + LOW_PRECISION)
def test_case05_tiny_optical_thickness(dtype):
  taus = np.logspace(-10, -3, 16)
  if dtype == jnp.float32:  # one ray of 16 samples; sigma carries the small factor
    t = _edges(np.full(16, 0.5), start=2.0)
    sigma = (taus / 0.5).astype(np.float32)
    rgb = np.ones((16, 3), np.float32)
  else:  # 16 rays of one sample; sigma = 1 in dtype, the float32 widths from 0 carry the factor
    t = np.stack([np.zeros(16), taus], axis=-1).astype(np.float32)
    sigma = jnp.ones((16, 1), dtype)
    rgb = jnp.ones((16, 1, 3), dtype)
  out, grads, grad_acc = _numpy(_composite_and_grads(rgb, sigma, t, BACKGROUND))
  _assert_finite(out, grads, grad_acc)
  # The float64 loop over the same (rounded) inputs.
  t_rows = t.reshape(-1, t.shape[-1])
  sigma_rows = np.asarray(sigma, np.float32).reshape(len(t_rows), -1)
  refs = [_reference_composite(np.ones((len(s), 3)), s, tt, BACKGROUND)
          for s, tt in zip(sigma_rows, t_rows)]
  np.testing.assert_allclose(out["weights"], np.reshape([r[0] for r in refs], sigma.shape),
                             rtol=1e-6, atol=0)
  np.testing.assert_allclose(out["acc"], np.reshape([1 - r[2] for r in refs], out["acc"].shape),
                             rtol=1e-6, atol=0)
  # Naive: 1 - exp(-tau) in float32 rounds to 0 below tau = 3e-8 (and is 40% off at 1e-7).
  ref = -np.expm1(-taus)
  naive = 1.0 - np.exp(-taus.astype(np.float32))
  assert np.all(naive[taus < 2.9e-8] == 0)
  assert np.max(np.abs(naive - ref)[taus > 1e-7] / ref[taus > 1e-7]) > 1e-2


# --- 6. Infinite or overflowing raw density, zero-width intervals ----------------------------

def _activated_loss(raw, t, name):
  rgb = jnp.full(raw.shape + (3,), 0.5, raw.dtype)
  return _render_loss(rgb, activations.density_activation(name)(raw), t, BACKGROUND)


@jax.jit
def _activated_composites_and_grads(raw, t):
  """For each density activation: composite of raw [R, S] over t, and d loss / d (raw, t)."""
  rgb = jnp.full(raw.shape + (3,), 0.5, raw.dtype)
  return {name: (rendering.composite(rgb, act(raw), t, BACKGROUND),
                 jax.grad(_activated_loss, argnums=(0, 1))(raw, t, name))
          for name, act in activations.DENSITY_ACTIVATIONS.items()}


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float16])  # float16 overflows; bf16 does not
def test_case06_infinite_density_and_zero_width_intervals(dtype):
  raw = jnp.array([[0.5, np.inf, 1.0, -np.inf],  # inf in a normal interval
                   [1e5, -1e5, 3.0, 2.0],  # overflows float16 (inf) and exp (88 clamp)
                   [np.inf, 1.0, np.inf, 0.5],  # inf in a zero-width interval (duplicated t)
                   [0.2, 0.3, 0.4, 0.5]], jnp.float32).astype(dtype)
  t = np.array([[2.0, 2.1, 2.3, 2.4, 2.6],
                [2.0, 2.1, 2.3, 2.4, 2.6],
                [2.0, 2.0, 2.2, 2.2, 2.6],  # intervals 0 and 2 have zero width
                [2.0, 2.0, 2.0, 2.0, 2.0]], np.float32)  # every interval has zero width
  results = _numpy(_activated_composites_and_grads(raw, t))
  for name, (out, grads) in results.items():
    _assert_finite(out, grads)
    np.testing.assert_array_equal(out["weights"][0, 2:], 0.0)  # nothing behind the inf sample
    np.testing.assert_array_equal(out["weights"][2, [0, 2]], 0.0)  # inf over zero width: no mass
    np.testing.assert_array_equal(out["acc"][3], 0.0)
    np.testing.assert_array_equal(out["rgb"][3], BACKGROUND)

  # Naive: without the density clamp, an infinite density times a zero width is inf·0 = NaN.
  with pytest.raises(FloatingPointError):
    _naive_weights(jax.nn.relu(raw[2:3].astype(jnp.float32)), t[2:3])


@jax.jit
def _activation_values_and_grads(raw, raw_low):
  """Each activation's values and gradients at float32 raw [N], and values at low-precision raw."""
  return {name: (jax.vmap(jax.value_and_grad(act))(raw), [act(r) for r in raw_low])
          for name, act in activations.DENSITY_ACTIVATIONS.items()}


def test_case06_activation_gradients_finite_over_raw_range():
  raw = np.concatenate([np.linspace(-1e5, 1e5, 101), [0.0, 88.0, 89.0, -np.inf, np.inf]])
  raw_low = [jnp.asarray(np.linspace(-6e4, 6e4, 9), dtype) for dtype in LOW_PRECISION]
  results = _numpy(_activation_values_and_grads(raw.astype(np.float32), raw_low))
  for (sigma, grad), sigma_low in results.values():
    _assert_finite(sigma[:-1], grad)  # finite values, and finite gradients even at ±inf
    assert sigma[-2] == 0 and sigma[-1] > 1e38  # raw = ±inf: sigma 0 and inf (exp: its clamp)
    for s in sigma_low:  # computed in float32: finite wherever raw is
      assert s.dtype == np.float32 and np.all(s >= 0)
      _assert_finite(s)

  # Naive: exp evaluated in float16 overflows at raw = 11.1; the compositing clamp gives that
  # sample a zero gradient, and the backward pass of exp multiplies it by exp(raw) = inf.
  clamped_f16_exp = lambda r: jnp.minimum(jnp.exp(r).astype(jnp.float32), quadrature.MAX_DENSITY)
  with pytest.raises(FloatingPointError):
    jax.grad(clamped_f16_exp)(jnp.asarray(12.0, jnp.float16))


# --- 7. near == far, and near == 0 with linear-in-disparity sampling -------------------------

@pytest.mark.parametrize("lindisp", [False, True])
@pytest.mark.parametrize("use_key", [False, True])
def test_case07_degenerate_bounds(lindisp, use_key):
  key = jax.random.PRNGKey(7) if use_key else None
  num = 16  # the shapes of tests/samplers/test_sampling.py, so the compilations are shared
  near = np.array([2.0, 0.0, 0.0, 0.0], np.float32)
  far = np.array([2.0, 0.0, 6.0, 1e-4], np.float32)
  t = np.asarray(_stratified(near, far, num, (4,), key, lindisp))
  _assert_finite(t)
  assert np.all(np.diff(t, axis=-1) >= 0)
  np.testing.assert_array_equal(t[:, 0], near)
  np.testing.assert_array_equal(t[:, -1], far)
  # near == far: every edge is near, the ray is empty: background colour, depth = far.
  np.testing.assert_array_equal(t[:2], np.broadcast_to(near[:2, None], (2, num + 1)))
  rgb = np.full((4, num, 3), 0.5, np.float32)
  sigma = np.ones((4, num), np.float32)
  out, grads, grad_acc = _numpy(_composite_and_grads(rgb, sigma, t, BACKGROUND))
  _assert_finite(out, grads, grad_acc)
  np.testing.assert_array_equal(out["rgb"][:2], np.broadcast_to(BACKGROUND, (2, 3)))
  np.testing.assert_array_equal(out["depth"][:2], far[:2])
  if lindisp and not use_key:
    # near = 0: 1/near is clamped to 1/1e-3, so the first interior edge is 1e-3·S/(S-1).
    np.testing.assert_allclose(t[2, 1], 1e-3 * num / (num - 1), rtol=1e-4)
  # Resampling these rays is finite and stays in [near, far] too.
  extra = np.asarray(_sample_pdf(t, out["weights"], 32, key, 0.01))
  _assert_finite(extra)
  assert np.all((extra >= near[:, None]) & (extra <= far[:, None]))

  if lindisp:
    # Naive: 1 / (1/near·(1 - s) + 1/far·s) with near = 0 is inf·0 = NaN at s = 1.
    with pytest.raises(FloatingPointError):
      _naive_lindisp(jnp.asarray(near[2]), jnp.asarray(far[2]), jnp.linspace(0.0, 1.0, num + 1))


@jax.jit
def _naive_lindisp(near, far, s):
  return 1.0 / (1.0 / near * (1.0 - s) + 1.0 / far * s)


# --- 8. Axis-parallel rays and a zero direction vector ---------------------------------------

def _field_render(directions):
  """Sample, encode and composite along rays from the origin: a stand-in for the field."""
  t = spacing.stratified(2.0, 6.0, 8, directions.shape[:1])
  points = directions[:, None, :] * spacing.midpoints(t)[..., None]
  feats = posenc.positional_encoding(points, 4)
  view = posenc.positional_encoding(rays.safe_normalize(directions), 2)
  sigma = jax.nn.softplus(jnp.sum(feats, -1))
  rgb = jax.nn.sigmoid(feats[..., :3] + view[:, None, :3])
  out = rendering.composite(rgb, sigma, t, jnp.ones(3))
  return jnp.sum(out["rgb"]) + jnp.sum(out["depth"])


def test_case08_axis_parallel_and_zero_directions():
  # An axis-aligned camera: the pixel at the principal point looks exactly down -z (the image
  # size of tests/cameras/test_rays.py, so the compilation is shared).
  get_rays = jax.jit(rays.get_rays, static_argnums=(0, 1))
  _, directions = get_rays(4, 6, 1.0, np.eye(4, dtype=np.float32), 0.0)
  directions = np.asarray(directions)
  np.testing.assert_array_equal(directions[2, 3], [0.0, 0.0, -1.0])
  dirs = np.concatenate([directions.reshape(-1, 3), np.zeros((1, 3), np.float32)])
  viewdirs = np.asarray(jax.jit(rays.safe_normalize)(dirs))
  _assert_finite(viewdirs)
  np.testing.assert_array_equal(viewdirs[-1], 0.0)  # documented: the zero vector maps to zero
  np.testing.assert_array_equal(viewdirs[2 * 6 + 3], [0.0, 0.0, -1.0])
  _assert_finite(jax.jit(jax.value_and_grad(_field_render))(dirs))

  # Naive: v / |v| at v = 0 is 0/0, and the gradient of |v| at 0 is NaN.
  with pytest.raises(FloatingPointError):
    jnp.zeros(3) / jnp.linalg.norm(jnp.zeros(3))
  with pytest.raises(FloatingPointError):
    jax.grad(jnp.linalg.norm)(jnp.zeros(3))


def _box_bounds_sum(origins, directions):
  t_min, t_max = rays.ray_box_bounds(origins, directions, 1.5, 2.0, 6.0)
  return jnp.sum(t_min) + jnp.sum(t_max), (t_min, t_max)


def test_case08_scene_box_bounds_of_axis_parallel_rays():
  """The scene-box path (renderer.py) divides by direction components: zeros must stay finite."""
  origins = np.array([[0.0, 0.0, 4.0], [0.0, 0.0, 4.0], [3.0, 0.0, 0.0], [0.0, 0.0, 4.0]],
                     np.float32)
  directions = np.array([[0.0, 0.0, -1.0],  # axis-parallel, hits the box
                         [0.0, 1.0, 0.0],  # parallel to the box's z slabs, outside them: misses
                         [0.0, 0.0, 1.0],  # parallel to the x slabs, outside them: misses
                         [0.0, 0.0, 0.0]], np.float32)  # zero direction
  grads, (t_min, t_max) = jax.jit(jax.grad(_box_bounds_sum, argnums=(0, 1), has_aux=True))(
      origins, directions)
  _assert_finite(grads, t_min, t_max)
  np.testing.assert_allclose([t_min[0], t_max[0]], [2.5, 5.5], rtol=1e-6)  # z from 1.5 to -1.5
  assert np.all(np.asarray(t_min) <= np.asarray(t_max))
  assert np.all((np.asarray(t_min) >= 2.0) & (np.asarray(t_max) <= 6.0))
  np.testing.assert_array_equal(np.asarray(t_min)[1:3], np.asarray(t_max)[1:3])  # misses


# --- 9. sample_pdf on hard weights ------------------------------------------------------------

def _piecewise_cdf(x, t, mass):
  """CDF at x (float64 [N]) of the density with `mass` [S] spread uniformly over [t_i, t_{i+1}]."""
  t, mass = np.asarray(t, np.float64), np.asarray(mass, np.float64) / np.sum(mass)
  return np.interp(x, t, np.concatenate([[0.0], np.cumsum(mass)]))


def _ks_statistic(samples, t, mass):
  """Kolmogorov-Smirnov distance between the samples' empirical CDF and the piecewise pdf."""
  x = np.sort(np.asarray(samples, np.float64))
  n = len(x)
  f = _piecewise_cdf(x, t, mass)
  return max(np.max(np.arange(1, n + 1) / n - f), np.max(f - np.arange(n) / n))


_T9 = np.array([2.0, 2.5, 3.0, 3.0, 3.0, 4.0, 4.5, 5.0, 6.0], np.float32)  # two zero-width bins
_W9 = {  # name: (weights [8], padding)
    "all_zero": (np.zeros(8), 0.01),
    "all_zero_unpadded": (np.zeros(8), 0.0),
    "one_hot": (np.eye(8)[5], 0.0),
    "zero_width_bins": (np.array([0.1, 0.3, 5.0, 7.0, 0.2, 0.0, 0.4, 0.1]), 0.0),
    "tiny_1e-30": (1e-30 * np.array([1.0, 3.0, 0.0, 0.0, 2.0, 0.5, 0.0, 4.0]), 0.0),
    "tiny_1e-30_padded": (np.full(8, 1e-30), 0.01),
}


@pytest.mark.parametrize("case", sorted(_W9))
def test_case09_sample_pdf_hard_weights(case):
  weights, padding = _W9[case]
  weights = weights.astype(np.float32)
  num = 2048
  samples = np.asarray(_sample_pdf(_T9, weights, num, jax.random.PRNGKey(9), padding))
  _assert_finite(samples)
  assert np.all(np.diff(samples) >= 0)
  assert np.all((samples >= _T9[0]) & (samples <= _T9[-1]))
  widths = np.diff(_T9.astype(np.float64))
  mass = np.where(widths > 0, np.maximum(weights, 0) + padding, 0.0)
  if mass.sum() == 0:  # documented fallback: uniform in t
    mass = widths
  if case == "one_hot":
    assert np.all((samples >= _T9[5]) & (samples <= _T9[6]))
  # Kolmogorov-Smirnov against the pdf; 1.95/sqrt(n) is the 0.1% critical value (fixed key).
  assert _ks_statistic(samples, _T9, mass) < 1.95 / math.sqrt(num)
  # The deterministic quantiles (k + 0.5)/N match the pdf to within 1/N.
  det = np.asarray(_sample_pdf(_T9, weights, 64, None, padding))
  assert np.all(np.diff(det) >= 0) and det[0] >= _T9[0] and det[-1] <= _T9[-1]
  assert _ks_statistic(det, _T9, mass) <= 1.0 / 64 + 1e-6

  if case == "all_zero_unpadded":
    # Naive: w / sum(w) with all-zero weights is 0/0.
    with pytest.raises(FloatingPointError):
      jnp.zeros(8) / jnp.sum(jnp.zeros(8))


def test_case09_naive_cdf_does_not_end_at_one():
  """Why the CDF is pinned: a float32 cumulative sum of a normalised pdf misses 1."""
  assert np.cumsum(np.full(10, 0.1, np.float32), dtype=np.float32)[-1] != 1.0


# --- 10. Positional encoding accuracy per band -------------------------------------------------

# Documented bound: against float64 sin/cos of the same float32 input, every band is within
# PE_ERROR (the float32 sin/cos rounding; 2^k·x is exact). Measured ~3.3e-8 on XLA:CPU.
PE_ERROR = 2.5e-7


@pytest.mark.parametrize("scale", [1.0, 1e3])
def test_case10_positional_encoding_accuracy(scale):
  num_freqs = 16
  x64 = np.random.default_rng(10).uniform(-scale, scale, 4096)
  x64[0] = scale
  x = x64.astype(np.float32)[:, None]
  out = np.asarray(jax.jit(posenc.positional_encoding, static_argnums=1)(x, num_freqs),
                   np.float64)
  xs = x[:, 0].astype(np.float64)  # the float32 input, exactly
  half_ulp = np.spacing(np.abs(x[:, 0])).astype(np.float64) / 2
  for k in range(num_freqs):
    y = 2.0 ** k * xs
    assert np.max(np.abs(out[:, 1 + 2 * k] - np.sin(y))) <= PE_ERROR, k
    assert np.max(np.abs(out[:, 2 + 2 * k] - np.cos(y))) <= PE_ERROR, k
    # Against the real-valued x before rounding to float32 the band also carries the input's
    # rounding amplified by 2^k: at most 2^k·ulp(x)/2 more. At x = 1e3, k = 15 that is ~1.
    err_true = np.abs(out[:, 1 + 2 * k] - np.sin(2.0 ** k * x64))
    assert np.all(err_true <= PE_ERROR + 2.0 ** k * half_ulp * 1.0001), k

  # Naive: cos(y) as sin(y + pi/2) rounds y + pi/2: at |x| <= 1 band 15 is off by ~1e-3, and at
  # x = 1e3 the top bands are off by order 1.
  y = (2.0 ** 15 * xs).astype(np.float32)
  naive = np.asarray(jax.jit(jnp.sin)(y + np.float32(np.pi / 2)), np.float64)
  assert np.max(np.abs(naive - np.cos(2.0 ** 15 * xs))) > (1e-4 if scale == 1.0 else 0.1)


# --- 11. Low-precision network outputs composited in float32 ---------------------------------

# Documented tolerance of compositing bfloat16 / float16 rgb and sigma against the exact composite
# of the float32 values they were rounded from: the unit roundoff u of the dtype for rgb and acc
# (colours in [0, 1]), and u·(t_S - t_0) for depth. The result is a convex combination of rounded
# colours, and the rounding of the densities moves the weights by about u·tau. Measured: about
# half of u.

@pytest.mark.parametrize("dtype", LOW_PRECISION)
def test_case11_low_precision_inputs_composite_in_float32(dtype):
  rays_, num = 32, 64
  rng = np.random.default_rng(11)
  scale = np.logspace(-2, 1, rays_)[:, None]  # opacities from ~0.06 to 1
  sigma = (scale * np.exp(rng.normal(0.0, 1.5, (rays_, num)))).astype(np.float32)
  t = _edges(rng.uniform(0.01, 0.1, (rays_, num)), start=2.0)
  rgb = rng.uniform(size=(rays_, num, 3)).astype(np.float32)
  refs = [_reference_composite(*a, BACKGROUND) for a in zip(rgb, sigma, t)]
  ref = {"rgb": np.stack([r[1] for r in refs]), "acc": np.array([1 - r[2] for r in refs]),
         "depth": np.array([r[3] for r in refs])}
  low, grads, grad_acc = _numpy(_composite_and_grads(
      jnp.asarray(rgb, dtype), jnp.asarray(sigma, dtype), t, BACKGROUND))
  assert all(v.dtype == np.float32 for v in low.values())
  _assert_finite(low, grads, grad_acc)
  u = UNIT_ROUNDOFF[dtype]
  np.testing.assert_allclose(low["rgb"], ref["rgb"], rtol=0, atol=u)
  np.testing.assert_allclose(low["acc"], ref["acc"], rtol=0, atol=u)
  np.testing.assert_allclose(low["depth"], ref["depth"], rtol=0,
                             atol=u * np.max(t[:, -1] - t[:, 0]))

  # Naive: compositing in the low precision itself is an order of magnitude worse than the
  # inputs' rounding, and the distances t cannot even be held in it (spacing near 4: bf16 0.03).
  tau = jnp.asarray(sigma, dtype) * jnp.asarray(np.diff(t, axis=-1), dtype)
  naive_acc = jnp.sum(_naive_weights(tau, jnp.arange(num + 1, dtype=dtype)), axis=-1)
  assert np.max(np.abs(np.asarray(naive_acc, np.float32) - ref["acc"])) > u
  assert np.max(np.abs(np.asarray(jnp.asarray(t, dtype), np.float32) - t)) > u


def _tiny_model(dtype):
  from nerf_jax.fields.networks import mlp  # pylint: disable=g-import-not-at-top
  from nerf_jax.fields.protocol import NetworkSettings  # pylint: disable=g-import-not-at-top
  return mlp.NerfMLP(mlp.Settings(depth=3, skip_layers=(1,)),
                     NetworkSettings(width=32, dtype=dtype))


def _numpy_init(model, inputs, seed):
  """Parameters of `model` drawn in numpy (LeCun normal kernels, zero biases): compiling
  flax's initialisers costs more than the test."""
  shapes = jax.eval_shape(model.init, jax.random.PRNGKey(0), inputs)["params"]
  rng = np.random.default_rng(seed)

  def draw(leaf):
    if len(leaf.shape) == 1:
      return np.zeros(leaf.shape, np.float32)
    return (rng.normal(size=leaf.shape) / math.sqrt(leaf.shape[0])).astype(np.float32)
  return jax.tree_util.tree_map(draw, shapes)


@jax.jit
def _mlp_composites_and_grads(params, feats, t):
  """Composites of the MLP run in float32 and in each low precision, with the gradients of the
  latter's losses."""
  def render(params, dtype):
    rgb, raw_sigma = _tiny_model(dtype).apply({"params": params}, feats)
    return rendering.composite(rgb, activations.relu(10.0 * raw_sigma), t, BACKGROUND)

  def loss(params, dtype):
    out = render(params, dtype)
    return jnp.sum(out["rgb"]) + jnp.sum(out["depth"]) + jnp.sum(out["acc"])

  return render(params, "float32"), {
      dtype: (render(params, dtype), jax.grad(loss)(params, dtype))
      for dtype in ("bfloat16", "float16")}


def test_case11_low_precision_mlp_composited():
  """The same parameters run in float32, bfloat16 and float16; the composites stay close.

  Documented tolerance for this 3-layer, 32-wide MLP: 8u for rgb and acc, and 8u·t_S for
  acc·depth = sum(w·t) (the conditional depth of a nearly empty ray is ill-conditioned, so depth
  is compared un-normalised). The matmul roundings add up over the layers; measured up to 3.5u over
  six initialisations. Deeper or wider nets need more.
  """
  rays_, num = 16, 32
  t = np.asarray(_stratified(2.0, 6.0, num, (rays_,), None, False))
  directions = np.random.default_rng(1).normal(size=(rays_, 3)).astype(np.float32)
  points = np.array([0.0, 0.0, 4.0]) + directions[:, None, :] * spacing.midpoints(t)[..., None]
  feats = posenc.positional_encoding(0.25 * points.astype(np.float32), 6)
  params = _numpy_init(_tiny_model("float32"), feats, seed=3)
  ref, lows = _numpy(_mlp_composites_and_grads(params, feats, t))
  assert np.min(ref["acc"]) < 0.1 and np.max(ref["acc"]) > 0.9  # empty and opaque rays
  for dtype, (low, grads) in lows.items():
    _assert_finite(low, grads)
    u = UNIT_ROUNDOFF[jnp.dtype(dtype).type]
    np.testing.assert_allclose(low["rgb"], ref["rgb"], rtol=0, atol=8 * u, err_msg=dtype)
    np.testing.assert_allclose(low["acc"], ref["acc"], rtol=0, atol=8 * u, err_msg=dtype)
    np.testing.assert_allclose(low["acc"] * low["depth"], ref["acc"] * ref["depth"], rtol=0,
                               atol=8 * u * 6.0, err_msg=dtype)


# --- 12. A full train step from a transparent and from an opaque start ------------------------

@functools.lru_cache(maxsize=None)
def _train_setup():
  """The debug config's model, optimizer and jitted train step (compiled once), and 2 views."""
  from nerf_jax.run import builders, experiment  # pylint: disable=g-import-not-at-top
  from nerf_jax.train import train_batches  # pylint: disable=g-import-not-at-top
  from tests.helpers import small_config  # pylint: disable=g-import-not-at-top
  exp = experiment.setup(small_config({"train.batch_rays": 64}))
  step = builders.make_train_step(exp)
  # Two views of a random 8x8 target from cameras 4 units from the origin; near 2, far 6.
  ray_list = [rays.get_rays(8, 8, 10.0, pose) for pose in rays.orbit_poses(num_frames=2)]
  data = train_batches.TrainData(
      rays=rays.Rays.create(jnp.stack([o.reshape(-1, 3) for o, _ in ray_list]),
                            jnp.stack([d.reshape(-1, 3) for _, d in ray_list]), 2.0, 6.0),
      rgb=jnp.asarray(np.random.default_rng(12).uniform(size=(2, 64, 3)), jnp.float32),
      acc=jnp.ones((2, 64), jnp.float32))
  return exp, step, data


@functools.lru_cache(maxsize=None)
def _jitted_init_state():
  from nerf_jax.run.signature import init_state  # pylint: disable=g-import-not-at-top
  exp, _, _ = _train_setup()
  return jax.jit(lambda: init_state(exp))  # one compile, not op by op


def _init_state():
  return _jitted_init_state()()


@pytest.mark.parametrize("start", ["transparent", "opaque"])
def test_case12_train_step_from_degenerate_start(start):
  exp, step, data = _train_setup()
  config, tx = exp.config, exp.tx
  assert config.model.density_activation == "relu" and config.model.density_noise == 0
  state = _init_state()
  # Push the density output's bias far out: raw sigma ~ -1e4 (sigma = 0, every ray empty and the
  # density gradient dead) or ~ +1e4 (every ray opaque at its first sample).
  params = jax.tree_util.tree_map(lambda x: x, state.params)
  bias = params["coarse"]["output"]["bias"]
  params["coarse"]["output"]["bias"] = bias.at[3].set(-1e4 if start == "transparent" else 1e4)
  state = state.replace(params=params, opt_state=jax.jit(tx.init)(params))
  before = _numpy(params)
  state, stats = step(state, data, jax.random.PRNGKey(0))
  _assert_finite(stats, state.params)
  assert int(state.bad_step) == -1  # the step saw a finite loss and finite gradients
  assert int(state.step) == 1
  moved = [np.any(a != np.asarray(b)) for a, b in zip(
      jax.tree_util.tree_leaves(before), jax.tree_util.tree_leaves(state.params))]
  # Opaque: the first sample's colour gets a gradient, so the step moves the weights. Transparent
  # with relu: every weight is 0 and the background is black, so every gradient is exactly 0.
  assert any(moved) == (start == "opaque")


# --- 13. Edges out to 1e10: rays into an unbounded scene ---------------------------------------

_stratified_unbounded = jax.jit(spacing.stratified_unbounded, static_argnums=(3, 4))


@pytest.mark.parametrize("far", [1e10, np.inf])
@pytest.mark.parametrize("use_key", [False, True])
def test_case13_edges_out_to_1e10(far, use_key):
  num = 16
  sigma = np.zeros((8, num), np.float32)  # ray 0: empty
  sigma[1] = 1e-12  # thin everywhere: the far interval alone has tau = 1e-2
  sigma[2] = np.exp(np.random.default_rng(13).normal(0.0, 3.0, num))  # log-normal
  sigma[3, -1] = 1e-8  # a sky: empty until the last interval, opaque over it (tau = 100)
  sigma[4, -1] = quadrature.MAX_DENSITY  # tau = 1e30·1e10 = inf in float32
  sigma[5] = quadrature.MAX_DENSITY  # opaque everywhere
  sigma[6, num // 2] = 1e3  # a surface just outside the inner region
  sigma[7] = np.inf  # an overflowing activation (clamped at MAX_DENSITY)
  key = jax.random.PRNGKey(13) if use_key else None
  t = _stratified_unbounded(0.5, 2.5, far, num, (8,), key, 0.5)
  assert float(t[0, -1]) == np.float32(1e10)  # far = inf: the last edge is 1e10
  rgb = np.random.default_rng(14).uniform(size=(8, num, 3)).astype(np.float32)
  out, grads, grad_acc = _numpy(_composite_and_grads(rgb, sigma, t, BACKGROUND))
  _assert_finite(out, grads, grad_acc)
  t = np.asarray(t)
  assert np.all(out["weights"] >= 0) and np.all((out["acc"] >= 0) & (out["acc"] <= 1))
  assert np.all((out["depth"] >= t[:, 0]) & (out["depth"] <= t[:, -1]))
  for r in range(8):
    weights, colour, trans, depth = _reference_composite(rgb[r], np.minimum(sigma[r], 1e30),
                                                         t[r], BACKGROUND)
    np.testing.assert_allclose(out["weights"][r], weights, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(out["rgb"][r], colour, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(out["acc"][r], 1.0 - trans, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(out["depth"][r], depth, rtol=1e-5)
  assert out["depth"][3] > 1e9  # the sky's depth: in its interval, not at the inner region

  # Naive: an edge at far = inf makes the last interval infinite, and an empty sample over it is
  # 0·inf = NaN. (In numpy: jax's eager dispatch may reuse a scalar op compiled in an earlier
  # module, whose NaN check debug_nans cannot then add.)
  with np.errstate(invalid="ignore"):
    assert np.isnan(np.float32(0.0) * (np.float32(np.inf) - t[0, -2]))
