"""The occupancy grid in NDC: the grid covers the box of the training rays (model.grid_box),
mapped onto its cube; samples go to the occupied cells along NDC's t in [0, 1]. Checked against
a brute-force walk of each ray's candidates, a density probed cell by cell, and a short run."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras.rays import Rays
from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state
from nerf_jax.samplers import occupancy
from nerf_jax.samplers.placement import Sampler
from tests.helpers import StandInNetwork, ray_renderer, small_config

BOX = (-1.3, -0.8, -1.0, 1.1, 0.9, 0.98)  # a training rays' NDC box: not a cube, not centred


def test_the_box_maps_onto_the_cube_and_back():
  low, high = np.array(BOX[:3]), np.array(BOX[3:])
  np.testing.assert_allclose(occupancy.to_cube(jnp.asarray(low), BOX), -1.0, atol=1e-6)
  np.testing.assert_allclose(occupancy.to_cube(jnp.asarray(high), BOX), 1.0, atol=1e-6)
  points = np.random.default_rng(0).uniform(low, high, (50, 3)).astype(np.float32)
  np.testing.assert_allclose(occupancy.from_cube(occupancy.to_cube(points, BOX), BOX), points,
                             atol=1e-6)


def _ndc_rays(count, seed=0):
  """NDC rays as a forward-facing camera makes them: from the near plane z = -1 to z = 1 at
  t = 1, spread across the box."""
  rng = np.random.default_rng(seed)
  start = np.stack([rng.uniform(-1.2, 1.0, count), rng.uniform(-0.7, 0.8, count),
                    -np.ones(count)], -1)
  end = np.stack([rng.uniform(-1.2, 1.0, count), rng.uniform(-0.7, 0.8, count),
                  np.ones(count)], -1)
  return Rays.create(start, end - start, 0.0, 1.0), start, end - start


def _brute_slots(origin, direction, mask, candidates, slots):
  """One ray's slots by walking its candidates: (starts, ends) of the occupied ones, grouped
  into `slots` as occupancy.py's docstring deals them."""
  res = mask.shape[0]
  low, high = np.array(BOX[:3]), np.array(BOX[3:])
  occupied = []
  for i in range(candidates):
    point = origin + direction * (i + 0.5) / candidates
    cell = np.clip(np.floor((point - low) / (high - low) * res), 0, res - 1).astype(int)
    if mask[tuple(cell)]:
      occupied.append(i)
  n, starts, ends = len(occupied), [], []
  for k in range(min(slots, n)):
    first, last = k * max(n, slots) // slots, min((k + 1) * max(n, slots) // slots, n) - 1
    starts.append(occupied[first] / candidates)
    ends.append((occupied[last] + 1) / candidates)
  return starts, ends


@pytest.mark.parametrize("share", [0.05, 0.6])  # few occupied cells (n <= K) and many (n > K)
def test_samples_lie_in_the_occupied_cells_of_the_boxed_grid(share):
  res, candidates, slots = 6, 48, 8
  mask = np.random.default_rng(1).uniform(size=(res,) * 3) < share
  grid = jnp.asarray(np.where(mask, 10.0, 0.0), jnp.float32)
  sampler = Sampler(slots, occupancy=occupancy.OccupancySettings(res, candidates),
                    occupancy_box=BOX)
  rays, origins, directions = _ndc_rays(40)
  samples = sampler.place(rays, None, grid)
  starts, ends = np.asarray(samples.t[:, 0:-1:2]), np.asarray(samples.t[:, 1::2])
  valid = np.asarray(samples.valid)
  for r in range(40):
    want_starts, want_ends = _brute_slots(origins[r], directions[r], mask, candidates, slots)
    assert valid[r].sum() == len(want_starts)
    np.testing.assert_allclose(starts[r][valid[r]], want_starts, atol=2e-6)
    np.testing.assert_allclose(ends[r][valid[r]], want_ends, atol=2e-6)
  assert valid.any() and valid.all() == (share > 0.5)  # many occupied: every slot used


def _brute_grid(density, res, probes):
  """The grid walked cell by cell in the box: the largest density at each cell's probe lattice
  (offsets (j + 0.5)/P - 0.5 cells per axis), then the largest of each 3x3x3 neighbourhood."""
  low, high = np.array(BOX[:3]), np.array(BOX[3:])
  h = (high - low) / res
  offsets = (np.arange(probes) + 0.5) / probes - 0.5
  cell_max = np.zeros((res,) * 3)
  for idx in np.ndindex(*cell_max.shape):
    lattice = np.stack(np.meshgrid(offsets, offsets, offsets, indexing="ij"), -1).reshape(-1, 3)
    cell_max[idx] = max(density(low + (np.array(idx) + 0.5 + o) * h) for o in lattice)
  pooled = np.zeros_like(cell_max)
  for idx in np.ndindex(*cell_max.shape):
    lo, hi = np.maximum(np.array(idx) - 1, 0), np.minimum(np.array(idx) + 2, res)
    pooled[idx] = cell_max[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]].max()
  return pooled


def test_the_grid_probes_the_field_at_the_points_of_the_box():
  config = small_config(**{"data.ndc": True, "data.scene_bound": 0.0,
                           "model.encoding": "grid",  # the stand-in sees raw points
                           "occupancy.enabled": True, "occupancy.resolution": 5,
                           "occupancy.probes": 2, "model.grid_box": BOX})
  weights = np.array([2.0, -1.0, 0.5])  # a density rising along x, falling along y: positive

  def colour_density(points):
    # Products and sums, not a matmul: exact float32 on any backend's matmul precision.
    return jnp.zeros(points.shape[:-1] + (3,)), 5.0 + jnp.sum(points * weights, axis=-1)

  rr = ray_renderer(config, StandInNetwork(colour_density))
  assert rr.sampler.occupancy_box == BOX
  grid = np.asarray(rr.occupancy_grid({"params": {"coarse": {}}}))
  want = _brute_grid(lambda p: 5.0 + p @ weights, 5, 2)
  np.testing.assert_allclose(grid, want, rtol=1e-5)


def test_a_forward_facing_run_trains_with_the_grid_and_records_its_box():
  config = small_config(**{"data.scene": "forward", "data.ndc": True, "data.scene_bound": 0.0,
                           "data.lindisp": False, "model.encoding": "grid",
                           "occupancy.enabled": True, "occupancy.resolution": 16,
                           "occupancy.candidates": 64, "occupancy.update_every": 2,
                           "num_samples": 12, "train.sample_budget": 1024})
  exp = experiment.setup(config)
  box = tuple(exp.config.model.grid_box)
  assert len(box) == 6 and exp.renderer.sampler.occupancy_box == box  # from the rays
  step, data = builders.make_train_step(exp), builders.make_train_data(exp)
  state = init_state(exp)
  first = None
  for _ in range(12):
    state, stats = step(state, data, jax.random.PRNGKey(0))
    first = float(stats["loss"]) if first is None else first
  assert np.isfinite(float(stats["loss"])) and float(stats["loss"]) < first
  grid = np.asarray(state.buffers["occupancy"])
  assert grid.max() > 0 and occupancy.occupied_mask(grid, 1.0).mean() < 1.0  # some cells empty
  out = builders.make_evaluator(exp)(state.variables, max_views=1)
  assert np.isfinite(out["psnr"])


def test_ndc_with_a_scene_box_is_refused_naming_the_field():
  config = small_config(**{"data.ndc": True, "data.scene_bound": 1.5, "occupancy.enabled": True})
  with pytest.raises(ValueError, match="config.data.scene_bound = 0"):
    builders.make_sampler(config)
