"""Density is per unit of world length on every rendering path: corner rays of a wide field of
view through the 'fog' scene's medium match the simulator's closed form (simulator.trace_medium),
and the marcher's stop test counts world-length optical depth."""

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.render import empty_space, image_renderer, renderer
from nerf_jax.run import builders
from nerf_jax.cameras import rays as rays_lib
from nerf_jax.cameras.rays import Rays
from nerf_jax.data.scenes import builtin, simulator
from tests.helpers import StandInNetwork, jitted, ray_renderer, small_config

FOG = builtin.SCENES["fog"].medium  # a sphere of radius 0.75, density 1.2, at the origin
NEAR, FAR = 1.0, 5.0


def _medium_alone(medium):
  """A stand-in network of the fog's medium alone (constant colour inside the ball)."""
  def colour_density(points):
    centre = jnp.asarray(medium.shape.center, jnp.float32)
    inside = jnp.sum((points - centre) ** 2, axis=-1) < medium.shape.radius ** 2
    rgb = jnp.broadcast_to(jnp.asarray(medium.color, jnp.float32), points.shape)
    return rgb, jnp.where(inside, medium.density, 0.0)
  return StandInNetwork(colour_density)


def _corner_rays(fov_degrees=60.0):
  """The rays through the four corners of a square image with this horizontal field of view (and
  its centre), as `rays.to_world` makes them (camera-space z = -1), each moved so that it passes
  through the fog's centre at t = 3 (z-depth)."""
  half = math.tan(math.radians(0.5 * fov_degrees))
  corners = [(sx * half, sy * half, -1.0) for sx in (-1, 1) for sy in (-1, 1)] + [(0, 0, -1.0)]
  _, d = rays_lib.to_world(jnp.asarray(corners, jnp.float32),
                           rays_lib.pose_spherical(30.0, -30.0, 4.0))
  d = np.asarray(d, np.float64)
  return np.asarray(FOG.shape.center) - 3.0 * d, d


# The debug config for each rendering path: 'grid' so positions go to the field as they are,
# 'relu' so the field's density passes unchanged.
PLAIN = {"model.encoding": "grid", "model.density_activation": "relu", "render.chunk": 8,
         "num_samples": 512, "render.march": False, "render.march_grid": 16}
PATHS = {"plain": PLAIN,
         "fine": {**PLAIN, "data.scene_bound": 1.5, "num_samples": 128, "num_fine_samples": 256},
         "occupancy": {**PLAIN, "data.scene_bound": 1.5, "occupancy.enabled": True,
                       "occupancy.resolution": 24, "occupancy.candidates": 1024},
         "march": {**PLAIN, "data.scene_bound": 1.5, "render.march": True}}


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
@pytest.mark.parametrize("path", ["plain", "fine", "occupancy", "march"])
def test_corner_rays_see_the_simulators_closed_form_fog(path):
  origins, directions = _corner_rays()
  norms = np.linalg.norm(directions, axis=-1)
  assert norms[:4].min() > 1.28  # corner rays of a 60° view are long: |d| = 1.29
  acc, rgb, depth_sum, _ = simulator.trace_medium(FOG, origins, directions, NEAR,
                                                  np.full(len(origins), FAR))
  # The physics: a chord of 1.5 world units at density 1.2 (not 1.5 / |d| units of t).
  np.testing.assert_allclose(acc, 1.0 - np.exp(-1.2 * 1.5), rtol=1e-6)
  config = small_config(PATHS[path])
  rr = ray_renderer(config, _medium_alone(FOG))
  variables = {"params": {"coarse": {}, "fine": {}}}
  if path == "occupancy":
    variables["occupancy"] = jitted(rr.occupancy_grid)(variables)
  rays = Rays.create(origins, directions, NEAR, FAR)
  if path == "march":
    settings = builders.image_settings(config)
    assert image_renderer.marches(rr, settings)
    out = image_renderer.make_image_renderer(rr, settings)(variables)(rays)
  else:
    out = renderer.final(jitted(rr.render)(variables, rays))  # jitted: one compile, not ~100
  np.testing.assert_allclose(out["acc"], acc, atol=5e-3)
  np.testing.assert_allclose(out["rgb"], rgb, atol=5e-3)
  np.testing.assert_allclose(out["depth"], depth_sum / acc, atol=1e-2)  # z-depth, as before


def test_the_marchers_stop_test_counts_world_length():
  """A dense ball: each ray stops after the round in which its optical depth, σ·|d|·δ summed in
  the test from the field's density, reaches -log(min_transmittance)."""
  origins, directions = _corner_rays()
  medium = dataclasses.replace(FOG, density=40.0)
  config = small_config(PATHS["march"], num_samples=256, **{"render.march_group": 4,
                                                            "render.min_transmittance": 1e-2})
  marcher = image_renderer._Marcher(  # pylint: disable=protected-access
      ray_renderer(config, _medium_alone(medium)), builders.image_settings(config))
  rays = Rays.create(origins, directions, NEAR, FAR)
  mask = jnp.ones((4, 4, 4), bool)
  t, t_world, points, occupied, rank, _ = marcher.plan(mask, None, rays)
  _, _, queried = empty_space.march(marcher.query_round, {"coarse": {}}, t_world, points,
                                    rays.viewdirs, occupied, rank, np.ones(len(origins), bool),
                                    4, 1e-2)
  # Brute force: the rounds each ray runs.
  t, points = np.asarray(t, np.float64), np.asarray(points, np.float64)
  sigma = np.where(np.sum(points ** 2, -1) < 0.75 ** 2, 40.0, 0.0)
  tau = np.cumsum(sigma * np.diff(t, axis=-1) * np.linalg.norm(directions, axis=-1)[:, None], -1)
  in_box = np.asarray(occupied)
  expected = 0
  for r in range(len(origins)):
    ranks = np.cumsum(in_box[r]) - 1
    depth = 0.0
    for k in range(-(-t.shape[1] // 4)):
      if depth >= -np.log(1e-2):
        break
      chosen = in_box[r] & (ranks // 4 == k)
      if not chosen.any():
        break
      expected += int(chosen.sum())
      depth = tau[r, np.flatnonzero(chosen)[-1]]
  assert queried == expected
  assert queried < 0.5 * in_box.sum()  # the rays do stop early
