"""The distortion loss against its O(S^2) definition, its analytic values, the normalised ray
distance it is measured in, and its place in the training loss; total variation against closed
forms and its place in the loss."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import rays
from nerf_jax.fields import registry
from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state
from nerf_jax.samplers import placement, spacing
from nerf_jax.train import regularizers
from tests.helpers import TINY_GRID, small_config


def brute_force(t, w):
  """mip-NeRF 360's eq. 15 as written: every pair of intervals, float64."""
  t, w = np.asarray(t, np.float64), np.asarray(w, np.float64)
  mids = 0.5 * (t[..., 1:] + t[..., :-1])
  pairs = np.abs(mids[..., :, None] - mids[..., None, :])
  return (np.einsum("...i,...j,...ij->...", w, w, pairs)
          + np.sum(w ** 2 * (t[..., 1:] - t[..., :-1]), axis=-1) / 3)


def test_distortion_matches_the_pairwise_definition():
  rng = np.random.default_rng(0)
  t = np.sort(rng.uniform(2.0, 6.0, (4, 7, 33)), axis=-1).astype(np.float32)
  t[..., 5] = t[..., 4]  # a zero-width interval, as occupancy sampling's gaps
  w = rng.uniform(0.0, 0.1, (4, 7, 32)).astype(np.float32)
  w[..., 10:14] = 0.0
  got = np.asarray(regularizers.distortion(jnp.asarray(t), jnp.asarray(w)))
  np.testing.assert_allclose(got, brute_force(t, w), rtol=2e-5, atol=1e-6)


def test_distortion_analytic_values():
  t = jnp.array([2.0, 2.5, 3.0, 5.0, 5.5])
  one = jnp.array([0.0, 0.8, 0.0, 0.0])  # all weight in one interval of length 0.5
  np.testing.assert_allclose(regularizers.distortion(t, one), 0.8 ** 2 * 0.5 / 3, rtol=1e-6)
  # Half of it on a floater at midpoint 2.25, half on the surface at midpoint 5.25: the pair
  # term 2 · 0.4 · 0.4 · 3.0 dominates; the spread ray costs far more than the compact one.
  split = jnp.array([0.4, 0.0, 0.0, 0.4])
  expected = 2 * 0.4 * 0.4 * 3.0 + (0.4 ** 2 * 0.5 + 0.4 ** 2 * 0.5) / 3
  np.testing.assert_allclose(regularizers.distortion(t, split), expected, rtol=1e-6)


def test_distortion_gradient_is_finite_and_analytic():
  t = jnp.linspace(2.0, 6.0, 17)
  w = jnp.zeros(16).at[3].set(0.2).at[12].set(0.7)  # zeros elsewhere: no NaN from them
  grad = np.asarray(jax.grad(lambda w: regularizers.distortion(t, w))(w))
  # dL/dw_i = 2 sum_j w_j |m_i - m_j| + 2/3 w_i (t_{i+1} - t_i)
  mids = np.asarray(0.5 * (t[1:] + t[:-1]))
  w = np.asarray(w)
  expected = 2 * np.abs(mids[:, None] - mids[None, :]) @ w + 2 / 3 * w * 0.25
  np.testing.assert_allclose(grad, expected, rtol=1e-5, atol=1e-6)
  # The smaller, far-away floater's weight costs more than the surface's.
  assert grad[3] > grad[12]


def one_step_stats(overrides):
  """The stats of one train step from a fresh state of small_config(overrides)."""
  exp = experiment.setup(small_config(overrides))
  step = builders.make_train_step(exp)
  _, stats = step(init_state(exp), builders.make_train_data(exp),
                  jax.random.PRNGKey(3))
  return stats


def test_the_train_loss_adds_the_weighted_distortion_and_nothing_else():
  stats = {w: one_step_stats({"loss.distortion.weight": w}) for w in (0.0, 0.5)}
  # Same render, same photometric error: only the loss grows, by a positive amount.
  np.testing.assert_allclose(stats[0.5]["colour/psnr"], stats[0.0]["colour/psnr"], rtol=1e-6)
  assert float(stats[0.5]["loss"]) > float(stats[0.0]["loss"]) * 1.001


@pytest.mark.parametrize("near,t_inner,far", [
    (0.5, 2.5, np.inf),  # starts inside the inner box: linear, then disparity out to 1e10
    (3.0, 1.0, np.inf),  # starts beyond it: all in disparity
    (0.5, 6.0, 4.0),  # ends inside it: all linear
])
def test_unbounded_unit_inverts_the_unbounded_strata(near, t_inner, far):
  num, shape = 24, (5,)
  for key in (None, jax.random.PRNGKey(7)):
    t = spacing.stratified_unbounded(near, t_inner, far, num, shape, key, 0.5)
    s = np.asarray(spacing.unbounded_unit(t, near, t_inner, far, 0.5))
    strata = np.asarray(spacing.stratified(0.0, 1.0, num, shape, key))  # the same s, in [0, 1]
    np.testing.assert_allclose(s, strata, atol=2e-5)


def test_unit_distance_does_not_depend_on_the_scene_scale():
  rng = np.random.default_rng(1)
  origins = rng.normal(size=(6, 3)).astype(np.float32)
  directions = rng.normal(size=(6, 3)).astype(np.float32)
  t = np.sort(rng.uniform(2.0, 6.0, (6, 17)), axis=-1).astype(np.float32)
  w = rng.uniform(0.0, 0.1, (6, 16)).astype(np.float32)
  bounded = placement.Sampler(16, scene_bound=3.0)
  losses = []
  for k in (1.0, 40.0):  # the same scene in units 40 times smaller: t, near, far scale by k
    scaled = rays.Rays.create(k * origins, directions, k * 2.0, k * 6.0)
    s = bounded.unit_distance(jnp.asarray(k * t), scaled)
    np.testing.assert_allclose(s, (t - 2.0) / 4.0, atol=1e-6)
    losses.append(regularizers.distortion(s, jnp.asarray(w)))
  np.testing.assert_allclose(losses[0], losses[1], rtol=1e-5)
  # In world units the loss would grow with the scale: what the normalisation removes.
  in_world_units = regularizers.distortion(jnp.asarray(40.0 * t), jnp.asarray(w))
  assert float(jnp.mean(in_world_units)) > 30 * float(jnp.mean(losses[0]))


def test_the_distortion_term_of_an_unbounded_scene_stays_below_its_weight():
  # Edges run out to 1e10: in t the term would be ~1e9 and drown the photometric loss; in s,
  # a ray's distortion is at most (sum of weights)^2 · 1 <= 1.
  unbounded = {"data.scene_bound": 0.5, "data.contraction": "linf"}
  stats = {w: one_step_stats({**unbounded, "loss.distortion.weight": w}) for w in (0.0, 0.5)}
  extra = float(stats[0.5]["loss"]) - float(stats[0.0]["loss"])
  assert 0.0 < extra <= 0.5


def test_total_variation_of_ramps_and_constants():
  i, j, k = np.meshgrid(np.arange(5.0), np.arange(4.0), np.arange(3.0), indexing="ij")
  ramp = jnp.asarray(np.stack([0.5 * i - 2.0 * k, 0.0 * i], axis=-1), jnp.float32)  # [5, 4, 3, 2]
  # Differences: 0.5 along x and -2 along z in channel 0, none in channel 1 (a mean over both).
  want = (0.25 + 0.0 + 4.0) / 2
  np.testing.assert_allclose(float(regularizers.total_variation(ramp, 3)), want, rtol=1e-6)
  assert float(regularizers.total_variation(jnp.full((6, 6, 3), 2.5), 2)) == 0.0
  # A single lattice point along an axis has no neighbour: no term, no NaN from an empty mean.
  line = jnp.asarray(np.arange(4.0)[:, None] * 3.0, jnp.float32)
  np.testing.assert_allclose(float(regularizers.total_variation(line, 1)), 9.0, rtol=1e-6)
  assert float(regularizers.total_variation(jnp.ones((1, 4)), 1)) == 0.0


def test_lattice_tables_and_the_weighted_tv_in_the_train_loss():
  params = {"coarse": {"grid_8": jnp.zeros((8, 8, 8, 2)), "plane_8_0": jnp.zeros((8, 8, 4)),
                       "line_8_0": jnp.zeros((8, 4)), "hidden": {"kernel": jnp.zeros((6, 4))}},
            "poses": jnp.zeros((3, 6))}
  every = {"grid_": 3, "density_": 3, "plane_": 2, "line_": 1}
  assert sorted(axes for _, axes in registry.lattice_tables(params, every)) == [1, 2, 3]
  # A family's own prefixes only (registry.Encoding.table_axes): the grid family's dense grids.
  grid_axes = registry.ENCODINGS.lookup("grid").table_axes
  assert [axes for _, axes in registry.lattice_tables(params, grid_axes)] == [3]
  stats = {}
  for weight in (0.0, 10.0):
    config = small_config(TINY_GRID, base="fast", **{"loss.total_variation.weight": weight})
    exp = experiment.setup(config)
    state = init_state(exp)
    tv = sum(float(regularizers.total_variation(t, a))
             for t, a in registry.lattice_tables(state.params, grid_axes))
    _, stats[weight] = builders.make_train_step(exp)(
        state, builders.make_train_data(exp), jax.random.PRNGKey(3))
  # Same render: only the loss grows, by the weight times the random start's variation.
  np.testing.assert_allclose(stats[10.0]["colour/psnr"], stats[0.0]["colour/psnr"], rtol=1e-6)
  np.testing.assert_allclose(float(stats[10.0]["loss"] - stats[0.0]["loss"]), 10.0 * tv,
                             rtol=1e-3)
