"""Structures thinner than a cell survive the skip grid (render-time marching) and the occupancy
grid (training): a thin slab and thin rods render the same marched and plain; jittered refreshes
find what one lattice of probes misses; a region emptied early comes back."""

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.render import image_renderer
from nerf_jax.run import builders
from nerf_jax.samplers import occupancy
from nerf_jax.cameras.rays import Rays
from tests.helpers import StandInNetwork, ray_renderer, small_config

BOUND = 1.5


NORMAL = np.array([0.0, 0.0, 1.0])  # axis-aligned: lattice probes line up in planes


def _slab(points, thickness=0.03, density=1000.0):
  """The issue's slab, |z| < thickness/2: on the fast config's skip grid it lies between the
  probe planes z = ±cell/4 of 2 probes per cell side."""
  return jnp.where(jnp.abs(points @ jnp.asarray(NORMAL, jnp.float32)) < 0.5 * thickness,
                   density, 0.0)


ROD_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.6, -0.48, 0.64]])
ROD_POINTS = np.array([[0.0, 0.1, -0.2], [0.3, 0.0, 0.0], [-0.2, 0.2, 0.1]])


def _rods(points, radius=0.045, density=1000.0):
  """Three straight rods of this radius (one along x, two oblique) through ROD_POINTS."""
  sigma = 0.0
  for axis, point in zip(ROD_AXES, ROD_POINTS):
    rel = points - jnp.asarray(point, jnp.float32)
    along = rel @ jnp.asarray(axis, jnp.float32)
    dist2 = jnp.sum(rel ** 2, axis=-1) - along ** 2
    sigma = jnp.maximum(sigma, jnp.where(dist2 < radius ** 2, density, 0.0))
  return sigma


def _rays_towards(targets, seed=0):
  """Rays from random points on a sphere of radius 4 through `targets` float [N, 3] (unit
  directions, t in [2, 6])."""
  rng = np.random.default_rng(seed)
  origins = rng.normal(size=targets.shape)
  origins = 4.0 * origins / np.linalg.norm(origins, axis=-1, keepdims=True)
  directions = targets - origins
  return Rays.create(origins, directions / np.linalg.norm(directions, axis=-1, keepdims=True),
                     2.0, 6.0)


def _marched_and_plain(sigma_fn, rays, config):
  rr, settings = ray_renderer(config, StandInNetwork(
      lambda p: (jax.nn.sigmoid(3.0 * p), sigma_fn(p)))), builders.image_settings(config)
  variables = {"params": {"coarse": {}}}
  assert image_renderer.marches(rr, settings)
  marched = image_renderer.make_image_renderer(rr, settings)(variables)(rays)
  plain_chunk = image_renderer.make_chunk_renderer(rr)
  plain = image_renderer.render_image(plain_chunk, variables, rays, chunk=config.render.chunk)
  return marched, plain


# The skip grid of the fast config (48^3 cells of 1/16 unit), density passed unchanged.
FAST = {"model.density_activation": "relu", "render.chunk": 256, "render.march_grid": 48}


def test_a_slab_thinner_than_a_cell_renders_the_same_marched_and_plain():
  rng = np.random.default_rng(1)
  on_slab = rng.uniform(-0.8, 0.8, (256, 3))
  on_slab -= (on_slab @ NORMAL)[:, None] * NORMAL  # targets on the slab's mid-plane
  config = small_config(FAST, base="fast", num_samples=384)  # spacing < the slab's 0.03
  cell = 2 * BOUND / config.render.march_grid
  assert 0.03 < 0.5 * cell
  marched, plain = _marched_and_plain(_slab, _rays_towards(on_slab), config)
  assert plain["acc"].min() > 0.99  # every ray hits the slab on the plain path
  np.testing.assert_allclose(marched["acc"], plain["acc"], atol=config.render.min_transmittance)
  np.testing.assert_allclose(marched["rgb"], plain["rgb"], atol=1e-3)


def test_rods_far_thinner_than_a_cell_render_the_same_marched_and_plain():
  config = small_config(FAST, base="fast", num_samples=512, **{
      "render.march_grid": 8,  # cells of 0.375: the rods are a quarter of a cell wide
      "render.march_probes": 8})  # guaranteed from √3·0.375/8 = 0.081 < 0.09
  rng = np.random.default_rng(2)
  k = rng.integers(0, 3, 256)
  targets = ROD_POINTS[k] + rng.uniform(-0.7, 0.7, (256, 1)) * ROD_AXES[k]
  marched, plain = _marched_and_plain(_rods, _rays_towards(targets, seed=3), config)
  assert np.mean(plain["acc"] > 0.5) > 0.5  # most rays see a rod on the plain path
  np.testing.assert_allclose(marched["acc"], plain["acc"], atol=config.render.min_transmittance)
  np.testing.assert_allclose(marched["rgb"], plain["rgb"], atol=1e-3)


def _refreshes(sigma_fns, config, start=None):
  """The occupancy grid after one refresh per density function in `sigma_fns`, as training
  refreshes it (jittered probes drawn from the step, accumulated with decay)."""
  oc = config.occupancy
  grid = jnp.zeros((oc.resolution,) * 3) if start is None else start
  run_key = jax.random.PRNGKey(0)
  for step, sigma_fn in enumerate(sigma_fns):
    grid = _refresh(sigma_fn, oc.resolution, oc.probes, oc.decay)(
        grid, jax.random.fold_in(run_key, step))
  return grid


_REFRESH = {}


def _refresh(sigma_fn, resolution, probes, decay):
  """One jitted refresh (grid, key) -> grid per density function (compiled once)."""
  if sigma_fn not in _REFRESH:
    _REFRESH[sigma_fn] = jax.jit(lambda grid, key: occupancy.accumulate(
        grid, occupancy.density_grid(sigma_fn, resolution, BOUND, probes, key), decay))
  return _REFRESH[sigma_fn]


def _slab_cells(resolution, thickness):
  """bool [R, R, R]: the cells the slab passes through (brute force: 6^3 points per cell)."""
  cell = 2 * BOUND / resolution
  sub = (np.arange(6) + 0.5) / 6
  corners = -BOUND + cell * np.stack(np.meshgrid(*[np.arange(resolution)] * 3, indexing="ij"), -1)
  offsets = cell * np.stack(np.meshgrid(sub, sub, sub, indexing="ij"), -1).reshape(-1, 3)
  dist = np.abs((corners[..., None, :] + offsets) @ NORMAL)
  return (dist < 0.5 * thickness + 0.5 * cell / 6 * np.sqrt(3)).any(-1)


def _thin_slab(points):
  return _slab(points, thickness=0.01)


def _ball(points):
  return jnp.where(jnp.sum((points - 0.6) ** 2, -1) < 0.3 ** 2, 50.0, 0.0)


def _floor(points):  # elsewhere in the box, always there
  return jnp.where(points[..., 2] < -1.0, 50.0, 0.0)


def test_jittered_refreshes_find_a_slab_that_one_lattice_misses():
  config = small_config({"occupancy.resolution": 12})  # cells of 0.25
  oc = config.occupancy
  thin = _thin_slab  # a twelfth of the probe spacing (0.125)
  fixed = occupancy.density_grid(thin, oc.resolution, BOUND, oc.probes)
  assert float(fixed.max()) == 0.0  # the unjittered lattice of this refresh misses it
  grid = _refreshes([thin] * 40, config)
  mask = np.asarray(occupancy.occupied_mask(grid, oc.threshold))
  cells = _slab_cells(oc.resolution, 0.01)
  assert mask[cells].all()  # every cell the slab crosses
  assert mask.mean() < 0.6  # and not the whole box


def test_a_region_emptied_early_comes_back_and_gone_density_fades():
  config = small_config({"occupancy.resolution": 12})  # cells of 0.25
  oc = config.occupancy
  both = lambda p: jnp.maximum(_ball(p), _floor(p))
  centre = (np.asarray(occupancy.cell_centres(oc.resolution, BOUND)) - 0.6) ** 2
  in_ball = centre.sum(-1) < 0.2 ** 2
  # Early in training the region is empty: the grid marks it so.
  early = _refreshes([_floor] * 3, config)
  assert not np.asarray(occupancy.occupied_mask(early, oc.threshold))[in_ball].any()
  # The field grows density there: the next refresh marks it again.
  back = _refreshes([both], config, start=early)
  assert np.asarray(occupancy.occupied_mask(back, oc.threshold))[in_ball].all()
  # Density that goes away fades: 50·0.95^n < threshold 1 after n = 77 refreshes.
  gone = _refreshes([_floor] * 80, config, start=back)
  assert not np.asarray(occupancy.occupied_mask(gone, oc.threshold))[in_ball].any()
