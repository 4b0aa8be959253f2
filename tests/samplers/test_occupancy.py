"""Occupancy grid: cell lookup, the grid of a known density field, sampling only occupied space,
rendering that matches dense sampling, and training with it (resumable, bitwise)."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.render import renderer
from nerf_jax.run import builders
from nerf_jax.samplers import occupancy
from nerf_jax.train import checkpoints
from nerf_jax.run import train_lib
from nerf_jax.cameras import rays as rays_lib
from nerf_jax.cameras.rays import Rays
from tests.helpers import params_equal, restored_variables
from tests.helpers import StandInNetwork, jitted, ray_renderer, small_config
from tests import helpers

BOUND = 1.5


def _rays(num, seed=0):
  """Rays from a sphere of radius 4 towards random points near the origin (unit directions)."""
  return helpers.sphere_rays(num, seed)


def _sphere_sigma(points, radius=0.5, density=50.0):
  return jnp.where(jnp.sum(points ** 2, axis=-1) < radius ** 2, density, 0.0)


def test_lookup_finds_the_cell_of_each_point():
  mask = np.zeros((4, 4, 4), bool)
  mask[1, 2, 3] = True
  cell = 2 * BOUND / 4
  inside = np.array([-BOUND + 1.5 * cell, -BOUND + 2.5 * cell, -BOUND + 3.5 * cell])
  points = jnp.asarray([inside, inside + [cell, 0, 0], inside + [0, 0, 0.49 * cell],
                        [9.0, 9.0, 9.0]], jnp.float32)
  got = occupancy.lookup(jnp.asarray(mask), points, BOUND)
  assert got.tolist() == [True, False, True, False]  # far outside clamps to cell [3, 3, 3]


def test_density_grid_of_a_sphere_covers_it_and_little_else():
  res = 16
  grid_values = occupancy.density_grid(_sphere_sigma, res, BOUND)
  mask = np.asarray(occupancy.occupied_mask(grid_values, threshold=1.0))
  centres = np.asarray(occupancy.cell_centres(res, BOUND))
  dist = np.linalg.norm(centres, axis=-1)
  cell = 2 * BOUND / res
  assert mask[dist < 0.5 - cell].all()  # every cell inside the sphere
  assert not mask[dist > 0.5 + 2.5 * cell].any()  # dilation reaches one cell beyond the probes
  assert 0 < mask.mean() < 0.2


def test_an_untrained_uniform_field_counts_as_occupied_everywhere():
  mask = occupancy.occupied_mask(jnp.full((8, 8, 8), 0.3), threshold=1.0)
  assert bool(mask.all())


def test_all_occupied_gives_stratified_intervals_tiling_the_segment():
  origins, directions = _rays(32)
  t_min, t_max = rays_lib.ray_box_bounds(origins, directions, BOUND, 2.0, 6.0)
  k = 16
  starts, ends, valid = occupancy.sample_occupied(jnp.ones((8, 8, 8), bool), origins, directions,
                                                  t_min, t_max, BOUND, 128, k)
  assert bool(valid.all())
  np.testing.assert_allclose(starts[:, 0], t_min, rtol=1e-6)
  np.testing.assert_allclose(ends[:, -1], t_max, rtol=1e-6)
  np.testing.assert_allclose(ends[:, :-1], starts[:, 1:], rtol=1e-6)
  widths = np.broadcast_to(((t_max - t_min) / k)[:, None], starts.shape)
  np.testing.assert_allclose(ends - starts, widths, rtol=1e-4, atol=1e-6)


def test_sparse_grid_samples_exactly_the_occupied_candidates():
  res, m, k = 8, 64, 32
  mask = np.zeros((res, res, res), bool)
  mask[3:5, 3:5, 3:5] = True  # the central cube [-0.375, 0.375]^3
  origins, directions = _rays(64, seed=1)
  t_min, t_max = rays_lib.ray_box_bounds(origins, directions, BOUND, 2.0, 6.0)
  starts, ends, valid = occupancy.sample_occupied(jnp.asarray(mask), origins, directions, t_min,
                                                  t_max, BOUND, m, k)
  starts, ends, valid = map(np.asarray, (starts, ends, valid))
  cell = 2 * BOUND / res
  for r in range(len(origins)):  # brute force: walk the candidates of each ray
    o, d = np.asarray(origins[r]), np.asarray(directions[r])
    edges = np.linspace(float(t_min[r]), float(t_max[r]), m + 1)
    mids = 0.5 * (edges[1:] + edges[:-1])
    cells = np.clip(np.floor((o + d * mids[:, None] + BOUND) / cell), 0, res - 1).astype(int)
    hits = [i for i in range(m) if mask[tuple(cells[i])]]
    assert len(hits) <= k
    assert valid[r].sum() == len(hits)
    np.testing.assert_allclose(starts[r, :len(hits)], edges[hits], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ends[r, :len(hits)], edges[np.array(hits, int) + 1], rtol=1e-5,
                               atol=1e-5)
    assert np.all(starts[r, len(hits):] == np.float32(t_max[r]))
    assert np.all(ends[r, len(hits):] == np.float32(t_max[r]))
  assert valid.any(axis=-1).sum() > 10 and not valid.any(axis=-1).all()  # hits and misses
  t = np.asarray(occupancy.interleave_gaps(starts, ends, t_max))
  assert np.all(np.diff(t, axis=-1) >= 0)  # slots and gaps: sorted, disjoint


def test_more_occupied_candidates_than_slots_are_grouped_in_rank_order():
  m, k = 40, 6
  occupied = np.asarray(jax.random.bernoulli(jax.random.PRNGKey(3), 0.5, (50, m)))
  occupied = np.concatenate([occupied, np.zeros((1, m), bool), np.ones((1, m), bool)])
  edges = np.cumsum(np.asarray(jax.random.uniform(jax.random.PRNGKey(4), (len(occupied), m + 1),
                                                  minval=0.1, maxval=1.0)), axis=-1)
  t_max = edges[:, -1]
  starts, ends, valid = map(np.asarray, occupancy.occupied_slots(
      jnp.asarray(edges, jnp.float32), jnp.asarray(occupied), k, jnp.asarray(t_max, jnp.float32)))
  assert (occupied.sum(-1) > k).sum() > 10  # most rays group several candidates per slot
  for r, row in enumerate(occupied):  # brute force: slot j spans ranks [j·n/K, (j+1)·n/K)
    hits = np.flatnonzero(row)
    per = max(len(hits), k)
    for j in range(k):
      ranks = [i for i in range(j * per // k, (j + 1) * per // k) if i < len(hits)]
      assert valid[r, j] == bool(ranks)
      want = (edges[r, hits[ranks[0]]], edges[r, hits[ranks[-1]] + 1]) if ranks else (
          t_max[r], t_max[r])
      np.testing.assert_allclose((starts[r, j], ends[r, j]), want, rtol=1e-6)


def _analytic_renderer(num_samples, use_occupancy):
  """The debug config's RayRenderer around a dense sphere with position-dependent colour
  ('grid': positions go to the field as they are), sampling the box of BOUND with `num_samples`,
  with or without occupancy."""
  return ray_renderer(small_config({
      "model.encoding": "grid", "data.scene_bound": BOUND, "num_samples": num_samples,
      "occupancy.enabled": use_occupancy, "occupancy.resolution": 24,
      "occupancy.candidates": 512}), StandInNetwork(
          lambda p: (jax.nn.sigmoid(3.0 * p), _sphere_sigma(p))))


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
def test_rendering_through_the_grid_matches_dense_sampling():
  # Jitted: one compile each, where op-by-op dispatch compiled ~200 small programs (~18 s).
  occ_renderer = _analytic_renderer(64, True)
  variables = {"params": {"coarse": {}}}
  variables["occupancy"] = jitted(occ_renderer.occupancy_grid)(variables)
  rays = Rays.create(*_rays(200, seed=2), 2.0, 6.0)
  fast = renderer.final(jitted(occ_renderer.render)(variables, rays))
  dense = renderer.final(jitted(_analytic_renderer(4096, False).render)(
      {"params": {"coarse": {}}}, rays))
  assert float(jnp.mean(dense["acc"] > 0.5)) > 0.2  # the rays do hit the sphere
  np.testing.assert_allclose(fast["acc"], dense["acc"], atol=0.02)
  np.testing.assert_allclose(fast["rgb"], dense["rgb"], atol=0.02)
  hit = np.asarray(dense["acc"]) > 0.99
  np.testing.assert_allclose(np.asarray(fast["depth"])[hit], np.asarray(dense["depth"])[hit],
                             atol=0.02)
  # Jittered (training) samples stay finite with gradients through the colour and density.
  key = jax.random.PRNGKey(0)
  loss = lambda o: jnp.sum(renderer.final(occ_renderer.render(
      variables, Rays.create(o, rays.directions, 2.0, 6.0), key=key))["rgb"])
  assert bool(jnp.all(jnp.isfinite(jitted(jax.grad(loss))(rays.origins))))


TRAIN = {"train.lr": 1e-2, "model.encoding": "grid", "model.grid.resolutions": (8, 16),
         "model.grid.features": 2, "model.density_activation": "softplus",
         "data.scene_bound": BOUND, "model.grid_bound": BOUND, "occupancy.enabled": True,
         "occupancy.resolution": 12, "occupancy.candidates": 64, "occupancy.update_every": 5}


def test_training_with_the_grid_resumes_bitwise_and_refreshes_the_grid(tmp_path):
  config = lambda: small_config(TRAIN, **{"train.max_steps": 20})
  full = train_lib.train_and_evaluate(config(), str(tmp_path / "full"))
  split = str(tmp_path / "split")
  train_lib.train_and_evaluate(config(), split)  # then "killed" after step 10:
  os.remove(os.path.join(checkpoints.checkpoint_dir(split), "ckpt_20.msgpack"))
  resumed = train_lib.train_and_evaluate(config(), split)
  assert resumed["steps"] == 20 and np.isfinite(full["psnr"])
  v_full, v_split = restored_variables(tmp_path / "full"), restored_variables(split)
  assert params_equal(v_full, v_split)  # the parameters and the occupancy grid
  assert v_full["occupancy"].shape == (12, 12, 12) and float(jnp.max(v_full["occupancy"])) > 0
  assert checkpoints.list_steps(split)[-1] == 20


def test_occupancy_config_errors_name_the_field():
  config = small_config(TRAIN, **{"train.max_steps": 1, "data.scene_bound": 0.0})
  with pytest.raises(ValueError, match="scene_bound"):
    builders.make_sampler(config)
  config = small_config(TRAIN, **{"train.max_steps": 1, "num_fine_samples": 8})
  with pytest.raises(ValueError, match="num_fine_samples"):
    builders.make_sampler(config)


def _compiled_gradient(levels, contracted):
  """The compiled text of the gradient of a render through occupancy-placed samples, by a
  field of `levels` grid levels: candidates of equal width in a box, or contracted ones
  (spaced in disparity: their edges are gathered)."""
  config = small_config(base="fast", **{
      "model.grid.resolutions": (4, 8, 16)[:levels], "occupancy.enabled": True,
      "occupancy.resolution": 8, "occupancy.candidates": 64, "num_samples": 16,
      "data.contraction": "linf" if contracted else ""})
  ray_renderer = builders.make_ray_renderer(config)
  variables = ray_renderer.init(jax.random.PRNGKey(0))
  origins, directions = _rays(64)
  rays = rays_lib.Rays.create(origins, directions, 2.0, 6.0)

  def loss(params):
    out = ray_renderer.render({**variables, "params": params}, rays)["coarse"]
    return jnp.sum(out["rgb"])
  return jax.jit(jax.grad(loss)).lower(variables["params"]).compile().as_text()


@pytest.mark.parametrize("contracted", [False, True])
def test_placed_slots_are_computed_once_not_inside_every_corner_gather(contracted):
  # Each trilinear level gathers 8 corners forward and scatters them backward. Were the
  # placement fused into those (XLA's CPU default), three levels would mention its search
  # loop's results and gathers far more often than one (2277 against 868 take_along_axis when
  # measured); computed once, equally often.
  one, three = (_compiled_gradient(levels, contracted) for levels in (1, 3))
  for name in ("take_along_axis", "searchsorted"):
    assert one.count(name) == three.count(name), name
  assert one.count("searchsorted") > 0
