"""The visual hull on the occupancy grid (renderer.occupancy_hull): a hull carved on the grid
itself is the grid's mask as it is; a subject's hull, with its own box and cells, is read at the
grid's cell centres. Before, the train step multiplied the grid by the hull array, which failed
on shapes (configs/detail.py's 128^3 grid, a subject's 96^3 hull) and mixed up boxes."""

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.render import renderer
from nerf_jax.samplers import occupancy
from nerf_jax.train import train_step
from nerf_jax.train.state import TrainState
from tests.helpers import TINY_GRID, jitted, ray_renderer, small_config

BOUND, CELLS = 1.5, 8  # the scene box's half-size and the occupancy grid's cells a side


def _renderer():
  return ray_renderer(small_config(TINY_GRID, base="fast", **{
      "occupancy.enabled": True, "occupancy.resolution": CELLS, "data.scene_bound": BOUND}))


def _brute_force(hull, hull_bound):
  """The hull's value at each occupancy cell's centre, one cell at a time."""
  res = hull.shape[0]
  out = np.zeros((CELLS,) * 3, np.float32)
  for index in np.ndindex(*out.shape):
    centre = (np.array(index) + 0.5) / CELLS * 2 * BOUND - BOUND
    if np.all(np.abs(centre) <= hull_bound):
      i, j, k = np.clip(((centre + hull_bound) / (2 * hull_bound) * res).astype(int), 0,
                        res - 1)
      out[index] = hull[i, j, k]
  return out


def test_a_hull_carved_on_the_grid_is_the_grid_mask_itself():
  hull = (np.random.default_rng(0).random((CELLS,) * 3) > 0.5).astype(np.float32)
  got = renderer.occupancy_hull(_renderer().sampler, jnp.asarray(hull), BOUND)
  np.testing.assert_array_equal(got, hull)


def test_a_subjects_hull_of_its_own_box_and_cells_is_read_at_the_cell_centres():
  hull = np.zeros((6, 6, 6), np.float32)  # over twice the box: 2/3 of its cells lie inside it
  hull[3:, 2:4] = 1.0
  got = renderer.occupancy_hull(_renderer().sampler, jnp.asarray(hull), 2 * BOUND)
  assert got.shape == (CELLS,) * 3
  np.testing.assert_array_equal(got, _brute_force(hull, 2 * BOUND))
  assert 0 < float(jnp.mean(got)) < 0.5


def test_the_refresh_keeps_the_cells_a_subjects_hull_carves_empty():
  rr = _renderer()
  variables = jitted(rr.init)(jax.random.PRNGKey(0))
  params = variables.pop("params")
  hull = np.zeros((6, 6, 6), np.float32)
  hull[3:] = 1.0  # x > 0 only
  buffers = {**variables, "hull": jnp.asarray(hull), "hull_bound": jnp.float32(2 * BOUND)}
  state = TrainState(step=jnp.int32(0), params=params, opt_state=(), bad_step=jnp.int32(-1),
                     buffers=buffers)
  key = jax.random.PRNGKey(1)
  grid = train_step.OccupancyRefresh(rr)(state, key)["occupancy"]
  probe_key = jax.random.fold_in(jax.random.fold_in(key, 0xFFFFFFFF), 0)
  unmasked = occupancy.accumulate(variables["occupancy"],
                                  rr.occupancy_grid({"params": params, **variables}, probe_key),
                                  rr.sampler.occupancy.decay)
  assert float(jnp.min(unmasked[: CELLS // 2])) > 0  # the untrained field fills the box
  np.testing.assert_allclose(grid, unmasked * _brute_force(hull, 2 * BOUND), rtol=1e-6)
