"""Marching with a field of cones (anti-aliased lattices, mip-NeRF's IPE): the marcher queries
each sample's frustum, as the plain path does, so `render.march` needs no turning off for cones.

The reference is the plain renderer over every sample (RayRenderer.render through
make_chunk_renderer); a field of points (the same parameters, cones dropped) is the tooth: the
cones change these wide pixels' colours, so a marcher that queried points would fail.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras.rays import Rays
from nerf_jax.render import image_renderer
from nerf_jax.run import builders
from tests import helpers
from tests.helpers import TINY_GRID, jitted, ray_renderer, small_config

RADIUS = 0.08  # pixel radius at unit distance: wide cones, so their blur shows
CONES = {"grid, one point": {"model.grid.antialias": True, "model.grid.multisample": False},
         "grid, six points": {"model.grid.antialias": True, "model.grid.multisample": True}}


def _config(cones, **render):
  return small_config({**TINY_GRID, **cones, **render}, base="fast")


def _rays():
  rays = Rays.create(*helpers.view_rays(12, 12, 15.0, 10.0, -30.0, 4.0), 2.0, 6.0)
  return rays.replace(radii=jnp.full(rays.shape, RADIUS, jnp.float32))


def _variables(rr):
  """`rr`'s variables with a sharp-edged dense blob (coloured by its parameters' noise)."""
  variables = jitted(rr.init)(jax.random.PRNGKey(0))
  level = variables["params"]["coarse"]["grid_16"]
  variables["params"]["coarse"]["grid_16"] = level.at[5:11, 4:10, 6:12].set(2.0)
  return variables


def _plain(rr, variables, rays):
  return image_renderer.render_image(image_renderer.make_chunk_renderer(rr), variables, rays,
                                     (0.0, 0.0, 0.0), 256)


@pytest.mark.parametrize("cones", list(CONES.values()), ids=list(CONES))
def test_marching_every_sample_is_the_plain_render_of_the_frustums(cones):
  config = _config(cones, **{"render.march_threshold": 0.0, "render.min_transmittance": 0.0})
  rr = ray_renderer(config)
  assert rr.field.cones and image_renderer.marches(rr, builders.image_settings(config))
  variables, rays = _variables(rr), _rays()
  plain = _plain(rr, variables, rays)
  marched = image_renderer.make_image_renderer(rr, builders.image_settings(config))(
      variables)(rays)
  assert float(np.max(plain["acc"])) > 0.5  # the blob is in view
  for k in ("rgb", "acc", "depth"):
    np.testing.assert_allclose(marched[k], plain[k], atol=2e-5, err_msg=k)
  points = _plain(dataclasses.replace(rr, field=dataclasses.replace(rr.field, cones="")),
                  variables, rays)
  assert float(np.max(np.abs(points["rgb"] - plain["rgb"]))) > 1e-2  # the cones matter here


def test_marching_cones_with_the_shipped_skip_settings_stays_within_the_skip_bound():
  config = _config(CONES["grid, one point"])
  rr = ray_renderer(config)
  settings = builders.image_settings(config)
  variables, rays = _variables(rr), _rays()
  plain = _plain(rr, variables, rays)
  marched = image_renderer.make_image_renderer(rr, settings)(variables)(rays)
  # empty_space.py's bound: the skipped cells' density along the box's diagonal, plus the
  # light left behind a terminated ray.
  bound = 1.0 - np.exp(-settings.march_threshold * 2.0 * np.sqrt(3.0) * config.data.scene_bound)
  assert np.max(np.abs(plain["acc"] - marched["acc"])) <= bound + settings.min_transmittance
  assert np.max(np.abs(plain["rgb"] - marched["rgb"])) <= bound + settings.min_transmittance
