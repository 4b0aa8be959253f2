"""placement.Sampler: ray bounds cut to the scene box, and `place` — stratified samples over the
box, or samples in the occupied cells of an occupancy grid — against brute force."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.samplers import occupancy, placement, spacing
from nerf_jax.samplers.occupancy import OccupancySettings
from nerf_jax.cameras.rays import Rays
from tests import helpers

BOUND, NEAR, FAR = 1.5, 1.0, 9.0  # every ray's box segment lies inside [NEAR, FAR]


def _rays(num, seed=0, spread=0.8):
  """Rays [num] from a sphere of radius 4 towards random points within `spread` of the origin
  (every one crosses the box of BOUND), directions not unit (|d| in [0.8, 1.25])."""
  return Rays.create(*helpers.sphere_rays(num, seed, spread, unit=False), NEAR, FAR)


def _box_bounds(rays, bound):
  """Brute force, float64: [t0, t1] of each ray inside [-bound, bound]^3 (slabs), within
  [near, far]."""
  o, d = np.asarray(rays.origins, np.float64), np.asarray(rays.directions, np.float64)
  a, b = (-bound - o) / d, (bound - o) / d
  t0 = np.maximum(np.minimum(a, b).max(-1), np.asarray(rays.near))
  t1 = np.minimum(np.maximum(a, b).min(-1), np.asarray(rays.far))
  return t0, np.maximum(t1, t0)


def test_bounds_are_the_box_segment_or_near_far_without_a_box():
  rays = _rays(64)
  t0, t1 = _box_bounds(rays, BOUND)
  assert np.all(t0 > NEAR) and np.all(t1 < FAR)  # the box cuts every ray on both sides
  got = placement.Sampler(16, BOUND).bounds(rays)
  np.testing.assert_allclose(got[0], t0, rtol=1e-5)
  np.testing.assert_allclose(got[1], t1, rtol=1e-5)
  near, far = placement.Sampler(16).bounds(rays)
  assert np.all(np.asarray(near) == NEAR) and np.all(np.asarray(far) == FAR)


@pytest.mark.parametrize("key", [None, jax.random.PRNGKey(3)])
@pytest.mark.parametrize("lindisp", [False, True])
def test_stratified_placement_is_stratified_sampling_over_the_box(key, lindisp):
  rays = _rays(64)
  samples = placement.Sampler(16, BOUND, lindisp).place(rays, key)
  t0, t1 = _box_bounds(rays, BOUND)
  expected = spacing.stratified(jnp.asarray(t0, jnp.float32), jnp.asarray(t1, jnp.float32), 16,
                                 rays.shape, key, lindisp=lindisp)
  np.testing.assert_allclose(samples.t, expected, rtol=1e-5)
  np.testing.assert_allclose(samples.distances, 0.5 * (samples.t[:, 1:] + samples.t[:, :-1]),
                             rtol=1e-6)
  assert samples.t.shape == (64, 17) and not samples.gapped and bool(samples.valid.all())
  if key is None and not lindisp:  # evenly spaced over the box segment
    np.testing.assert_allclose(samples.t, np.linspace(t0, t1, 17, axis=-1), rtol=1e-5)


def _grid(mask):
  """An occupancy grid float32 [R, R, R]: density 10 in the cells of `mask`, 0 elsewhere."""
  return jnp.asarray(np.where(mask, 10.0, 0.0), jnp.float32)


def _cell(points, res):
  """Brute force: int [..., 3], the cell of [-BOUND, BOUND]^3 (res per side) holding each point."""
  return np.clip(np.floor((np.asarray(points, np.float64) + BOUND) / (2 * BOUND) * res), 0,
                 res - 1).astype(int)


def test_occupancy_placement_on_a_grid_occupied_everywhere_is_stratified():
  """The grid before any refresh (zeros: occupied everywhere) gives each ray plain stratified
  samples over its box segment: slot k spans candidates [k·M/K, (k+1)·M/K)."""
  settings = OccupancySettings(resolution=8, candidates=64)
  rays = _rays(32, seed=1)
  samples = placement.Sampler(16, BOUND, occupancy=settings).place(rays, None,
                                                                 settings.empty_grid())
  plain = placement.Sampler(16, BOUND).place(rays)
  assert samples.gapped and bool(samples.valid.all())
  np.testing.assert_allclose(samples.distances, plain.distances, rtol=1e-5)
  np.testing.assert_allclose(samples.t[:, ::2], plain.t, rtol=1e-5)  # the gaps are zero-width
  np.testing.assert_allclose(samples.t[:, 1::2], plain.t[:, 1:], rtol=1e-5)


@pytest.mark.parametrize("key", [None, jax.random.PRNGKey(4)])
def test_occupancy_placement_puts_every_sample_in_an_occupied_cell(key):
  res, m, k = 8, 64, 64  # K = M: every occupied candidate gets a slot of its own
  mask = np.zeros((res, res, res), bool)
  mask[3:5, 3:5, 3:5] = True  # the central cube [-0.375, 0.375]^3
  mask[0, 7, 2] = True  # and a corner cell
  settings = OccupancySettings(resolution=res, candidates=m, threshold=1.0)
  np.testing.assert_array_equal(occupancy.occupied_mask(_grid(mask), 1.0), mask)
  rays = _rays(128, seed=2, spread=0.6)
  samples = placement.Sampler(k, BOUND, occupancy=settings).place(rays, key, _grid(mask))
  distances, valid = np.asarray(samples.distances, np.float64), np.asarray(samples.valid)
  points = np.asarray(rays.origins)[:, None] + np.asarray(rays.directions)[:, None] * \
      distances[..., None]
  t0, t1 = _box_bounds(rays, BOUND)
  width = (t1 - t0) / m
  within = []  # where in its candidate each valid sample lies, in [0, 1)
  for r in range(len(valid)):
    # Brute force: the occupied candidates of the ray (their midpoints' cells).
    mids = t0[r] + width[r] * (np.arange(m) + 0.5)
    cells = _cell(np.asarray(rays.origins[r]) + np.asarray(rays.directions[r]) * mids[:, None],
                  res)
    hits = np.flatnonzero(mask[cells[:, 0], cells[:, 1], cells[:, 2]])
    assert valid[r].sum() == len(hits)
    # Each valid sample lies in its own occupied candidate, in order.
    position = (distances[r, valid[r]] - t0[r]) / width[r]
    np.testing.assert_array_equal(np.floor(position).astype(int), hits)
    within.append(position % 1.0)
    if key is None:  # at the candidate's midpoint: in an occupied cell
      here = _cell(points[r, valid[r]], res)
      assert mask[here[:, 0], here[:, 1], here[:, 2]].all()
  assert valid.sum() > 500 and 50 < valid.any(-1).sum() < len(valid)  # hits and misses
  t = np.asarray(samples.t)
  assert samples.gapped and t.shape == (128, 2 * k + 1) and np.all(np.diff(t, axis=-1) >= 0)
  within = np.concatenate(within)
  if key is None:
    np.testing.assert_allclose(within, 0.5, atol=1e-3)
  else:  # jittered over the candidates (uniform: std 0.29), not at their midpoints
    assert np.std(within) > 0.2


def test_points_and_world_length_scale_by_the_direction():
  rays = _rays(8)
  t = jnp.linspace(NEAR, FAR, 5)[None].repeat(8, 0)
  o, d = np.asarray(rays.origins, np.float64), np.asarray(rays.directions, np.float64)
  np.testing.assert_allclose(placement.points(rays, t), o[:, None] + d[:, None] * np.asarray(
      t)[..., None], rtol=1e-6, atol=1e-6)
  norm = np.linalg.norm(d, axis=-1)[:, None]
  np.testing.assert_allclose(placement.world_t(t, rays), np.asarray(t) * norm, rtol=1e-6)
  np.testing.assert_allclose(placement.per_unit_t(jnp.ones((8, 5)), rays),
                             np.broadcast_to(norm, (8, 5)), rtol=1e-6)
