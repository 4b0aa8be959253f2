"""A fixed sample budget (train.sample_budget): the field is queried only at the first B valid
samples of a batch, compacted. Rays whose samples all fit render exactly as without a budget,
in values and gradients; the others are flagged and left out of the loss."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.render import renderer
from nerf_jax.run import builders
from nerf_jax.train import losses
from nerf_jax.train.losses import colour
from tests.helpers import SPLIT_GRID, TINY_GRID, ball_in_first_density_level, jitted
from tests.helpers import small_config, small_view_rays


def _brute_slots(valid, budget):
  """The first `budget` valid (ray, sample) pairs in ray order, and the rays all of whose valid
  samples are among them, by walking the mask."""
  slots, complete = [], []
  for r, row in enumerate(valid):
    for s, v in enumerate(row):
      if v and len(slots) < budget:
        slots.append(r * valid.shape[1] + s)
    complete.append(sum(int(v) for v in valid[:r + 1].reshape(-1)) <= budget)
  return slots, np.array(complete)


@pytest.mark.parametrize("budget", [1, 7, 20, 200])
def test_budgeted_slots_match_a_walk_over_the_mask(budget):
  valid = np.array(jax.random.bernoulli(jax.random.PRNGKey(budget), 0.3, (9, 6)))
  valid[2] = False  # an empty ray is complete whenever the rays before it are
  slots, complete = renderer.budgeted_slots(jnp.asarray(valid), budget)
  want_slots, want_complete = _brute_slots(valid, budget)
  slots = np.asarray(slots)
  np.testing.assert_array_equal(slots[:len(want_slots)], want_slots)
  assert np.all(slots[len(want_slots):] == valid.size)  # padding: dropped by the scatter
  np.testing.assert_array_equal(complete, want_complete)


@functools.lru_cache(maxsize=None)  # built once per worker for both tests; they only read it
def _renderers(split):
  """(plain, budgeted renderer factory, variables) with occupancy: a ball-shaped field and the
  occupancy grid of it, so that some rays have no valid sample and others many. The split
  field shades every sample in the budget (colour_fraction 1: a share of the budget, or of
  all slots without one), so both renderers colour every sample with weight."""
  fields = {**(SPLIT_GRID if split else {**TINY_GRID, "num_samples": 24}),
            "occupancy.enabled": True,
            "occupancy.resolution": 16, "model.colour_fraction": 1.0 if split else 0.0}
  config = small_config(base="fast", **fields)
  plain = builders.make_ray_renderer(config)
  variables = jitted(plain.init)(jax.random.PRNGKey(0))
  if split:
    variables["params"]["coarse"] = ball_in_first_density_level(variables["params"]["coarse"])
  else:  # a random field is dense enough to fill some cells and not others
    variables["params"]["coarse"] = jax.tree_util.tree_map(
        lambda p: p * 3.0, variables["params"]["coarse"])
  variables["occupancy"] = jitted(plain.occupancy_grid)(variables)
  with_budget = lambda b: dataclasses.replace(plain, sample_budget=b)
  return plain, with_budget, variables


def _valid_counts(plain, variables, rays):
  samples = jitted(plain.sampler.place)(rays, None, variables["occupancy"])
  return np.asarray(samples.valid).sum(-1)


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
@pytest.mark.parametrize("split", [True, False])
def test_rays_within_the_budget_render_as_without_it(split):
  plain, with_budget, variables = _renderers(split)
  rays = small_view_rays()
  counts = _valid_counts(plain, variables, rays)
  assert (counts == 0).any() and counts.max() > 4  # the test has empty and full rays
  total = int(counts.sum())
  want = jitted(plain.render)(variables, rays)["coarse"]
  whole = jitted(with_budget(total).render)(variables, rays)["coarse"]
  assert bool(np.all(whole["complete"]))
  for name in ("rgb", "acc", "depth"):
    np.testing.assert_allclose(whole[name], want[name], atol=2e-6, err_msg=name)
  budget = total // 2
  half = jitted(with_budget(budget).render)(variables, rays)["coarse"]
  complete = np.asarray(half["complete"])
  np.testing.assert_array_equal(complete, np.cumsum(counts) <= budget)
  assert complete.any() and not complete.all()
  # Every ray's valid samples, the ones past the budget too: what the batch asked of it.
  np.testing.assert_array_equal(half["valid_samples"], counts)
  np.testing.assert_allclose(np.asarray(half["rgb"])[complete], np.asarray(want["rgb"])[complete],
                             atol=2e-6)
  np.testing.assert_allclose(np.asarray(half["acc"])[complete], np.asarray(want["acc"])[complete],
                             atol=2e-6)


@pytest.mark.parametrize("split", [True, False])
def test_the_gradient_of_complete_rays_is_unchanged_by_the_budget(split):
  plain, with_budget, variables = _renderers(split)
  rays = small_view_rays()
  counts = _valid_counts(plain, variables, rays)
  budget = int(counts.sum()) // 2
  complete = jnp.asarray(np.cumsum(counts) <= budget)

  def loss(params, ray_renderer):
    out = ray_renderer.render({**variables, "params": params}, rays)["coarse"]
    return jnp.sum(jnp.where(complete[:, None], (out["rgb"] - 0.3) ** 2, 0.0))
  # Full float32 matmuls: a GPU's TF32 rounds the budget's gathered batch and the plain one
  # differently (their shapes differ), beyond rtol 1e-4 on an H200; the sums are what is tested.
  with jax.default_matmul_precision("highest"):
    want = jitted(jax.grad(loss), ray_renderer=plain)(variables["params"])
    got = jitted(jax.grad(loss), ray_renderer=with_budget(budget))(variables["params"])
  for g, w in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want)):
    np.testing.assert_allclose(g, w, rtol=1e-4, atol=1e-7)
  assert any(float(jnp.abs(w).sum()) > 0 for w in jax.tree_util.tree_leaves(want))


def test_the_loss_leaves_out_incomplete_rays():
  rgb = jax.random.uniform(jax.random.PRNGKey(0), (6, 3))
  target = jax.random.uniform(jax.random.PRNGKey(1), (6, 3))
  complete = jnp.array([True, True, False, True, False, False])
  keep = np.asarray(complete)
  want = np.mean((np.asarray(rgb)[keep] - np.asarray(target)[keep]) ** 2)
  np.testing.assert_allclose(colour.mse(rgb, target, complete), want, rtol=1e-6)
  np.testing.assert_allclose(colour.mse(rgb, target), np.mean(
      (np.asarray(rgb) - np.asarray(target)) ** 2), rtol=1e-6)
  assert float(colour.mse(rgb, target, jnp.zeros(6, bool))) == 0.0  # finite, not 0/0


def test_the_colour_loss_reports_what_the_rays_asked_of_the_budget():
  rgb = jax.random.uniform(jax.random.PRNGKey(0), (6, 3))
  target = jax.random.uniform(jax.random.PRNGKey(1), (6, 3))
  complete = jnp.array([True, True, True, False, False, False])
  valid_samples = jnp.array([3, 0, 5, 7, 2, 0], jnp.int32)
  outputs = {"coarse": {"rgb": rgb, "complete": complete, "valid_samples": valid_samples}}
  loss, stats = colour.Colour()(losses.LossInputs(outputs, target, None, {}))
  assert int(stats["rays_in_loss"]) == 3
  assert int(stats["samples_wanted"]) == 17  # 3 + 0 + 5 + 7 + 2 + 0, fitted or not
  keep = np.asarray(complete)
  np.testing.assert_allclose(loss, np.mean((np.asarray(rgb)[keep] - np.asarray(target)[keep])
                                           ** 2), rtol=1e-6)
  _, plain = colour.Colour()(losses.LossInputs({"coarse": {"rgb": rgb}}, target, None, {}))
  assert set(plain) == {"psnr"}  # no budget, no budget stats


def test_a_budget_needs_the_occupancy_grid():
  config = small_config(base="fast", **{"train.sample_budget": 1000})
  with pytest.raises(ValueError, match="occupancy.enabled"):
    builders.make_ray_renderer(config)
