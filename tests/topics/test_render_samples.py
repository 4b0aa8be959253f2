"""render.num_samples: more samples per ray in renders than in training.

A field trained on jittered samples has learnt the integral they estimate; a deterministic render
estimates it better with more samples. The tests check that the setting reaches both image paths
(plain and marching) and that the images it draws are closer to a brute-force 1024-sample render
than those drawn with the training's count.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.render import image_renderer, renderer
from nerf_jax.run import builders
from nerf_jax.cameras.rays import Rays
from tests.helpers import TINY_GRID, jitted, ray_renderer, small_config
from tests import helpers

TRAINED, RENDERED = 8, 32  # samples per ray in training and in renders


def _config(fields=TINY_GRID, **more):
  """The tiny grid config (`fields`: TINY_GRID and changes, on base="fast") with `more`."""
  return small_config(fields, base="fast", **more)


def _blob_variables(rr):
  """Variables of `rr` with a sharp-edged dense blob in the middle of the box (a trained toy)."""
  variables = jitted(rr.init)(jax.random.PRNGKey(0))
  level = variables["params"]["coarse"]["grid_16"]
  variables["params"]["coarse"]["grid_16"] = level.at[5:11, 4:10, 6:12].set(2.0)
  return variables


def _rays():
  return Rays.create(*helpers.view_rays(12, 12, 15.0, 10.0, -30.0, 4.0), 2.0, 6.0)


def _draw(config, variables, rays):
  """The image of `config`'s renderer and render settings (builders.image_settings)."""
  rr = ray_renderer(config)
  return image_renderer.make_image_renderer(rr, builders.image_settings(config))(variables)(rays)


def test_zero_keeps_the_renderer_and_a_count_replaces_only_the_sampler():
  rr = ray_renderer(_config(num_samples=TRAINED))
  assert image_renderer.with_samples(rr, 0) is rr
  more = image_renderer.with_samples(rr, RENDERED)
  assert more.sampler.num_samples == RENDERED and rr.sampler.num_samples == TRAINED
  assert more.field is rr.field and more.sampler.scene_bound == rr.sampler.scene_bound


def test_more_render_samples_approach_the_brute_force_image_on_both_paths():
  rays = _rays()
  variables = _blob_variables(ray_renderer(_config(num_samples=TRAINED)))
  reference = renderer.final(jitted(ray_renderer(_config(num_samples=1024)).render)(variables,
                                                                                    rays))
  assert float(jnp.max(reference["acc"])) > 0.5  # the blob is in view
  for march in (False, True):
    fields = {**TINY_GRID, "render.march": march, "render.min_transmittance": 0.0,
              "render.march_threshold": 0.0}
    as_trained = _draw(_config(fields, num_samples=TRAINED), variables, rays)
    more = _draw(_config(fields, num_samples=TRAINED, **{"render.num_samples": RENDERED}),
                 variables, rays)
    same_count = _draw(_config(fields, num_samples=RENDERED), variables, rays)
    for k in ("rgb", "acc"):
      np.testing.assert_allclose(more[k], same_count[k], atol=1e-5)
      error = lambda image: float(np.mean(np.abs(image[k] - np.asarray(reference[k]))))
      assert error(more) < 0.5 * error(as_trained), (march, k, error(more), error(as_trained))


def test_a_negative_count_is_refused_naming_the_field():
  with pytest.raises(ValueError, match="config.render.num_samples=-4"):
    builders.image_settings(small_config(**{"render.num_samples": -4}))
