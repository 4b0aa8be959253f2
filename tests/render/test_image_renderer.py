"""render.chunk = 0: rays per render call sized from the device's memory. The size follows the
free memory and a ray's bytes; the CPU (no memory reported) keeps today's chunk; and an image
rendered in device-sized chunks is the image rendered in fixed chunks, on the plain path and on
the marching one."""

import dataclasses

import jax
import numpy as np
import pytest

from nerf_jax.cameras.rays import camera_rays, pose_spherical
from nerf_jax.render import image_renderer
from nerf_jax.render.image_renderer import ImageSettings
from nerf_jax.run import builders, config_lib
from tests.helpers import PATHS_RTOL, ray_renderer, small_config


def test_sized_chunk_is_the_largest_power_of_two_that_fits_within_bounds():
  share = image_renderer.MEMORY_SHARE
  assert image_renderer.sized_chunk(4096 * 1000 / share, 1000) == 4096
  assert image_renderer.sized_chunk(4095 * 1000 / share, 1000) == 2048
  assert image_renderer.sized_chunk(1e15, 1000) == image_renderer.MAX_CHUNK
  assert image_renderer.sized_chunk(1.0, 1000) == image_renderer.MIN_CHUNK
  assert image_renderer.sized_chunk(0.0, 0.0) == image_renderer.MIN_CHUNK


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="a CPU reports no memory")
def test_the_cpu_reports_no_memory_and_keeps_todays_chunk(capsys):
  assert image_renderer.device_memory() is None
  rr = ray_renderer(small_config())
  chunk = image_renderer.device_chunk(rr, rr.init(jax.random.PRNGKey(0)))
  assert chunk == image_renderer.FALLBACK_CHUNK == config_lib.default().render.chunk == 4096
  assert ImageSettings().chunk == 4096
  assert "render chunk: 4096 rays per call (the device reports no memory)" in \
      capsys.readouterr().out


def test_a_negative_chunk_is_refused_naming_the_field():
  rr = ray_renderer(small_config())
  with pytest.raises(ValueError, match="config.render.chunk=-1"):
    image_renderer.make_image_renderer(rr, ImageSettings(chunk=-1))


# debug.py's MLP samples [near, far]: the plain path. fast.py's grids in their box: marching.
PLAIN = {}
MARCHING = {"model.grid.resolutions": (8, 16), "num_samples": 24, "render.march_grid": 8}


@pytest.mark.parametrize("base, fields, marches", [("debug", PLAIN, False),
                                                    ("fast", MARCHING, True)])
def test_device_sized_chunks_render_the_image_fixed_chunks_render(base, fields, marches):
  config = small_config(fields, base=base)
  rr = ray_renderer(config)
  settings = builders.image_settings(config)
  assert image_renderer.marches(rr, settings) == marches
  variables = rr.init(jax.random.PRNGKey(0))  # a random field: the paths must agree anyway
  # Free memory for exactly MIN_CHUNK rays of this renderer, so the 40 x 40 image (1600 rays)
  # takes two device-sized calls against seven fixed ones of 256.
  ray_bytes = image_renderer.bytes_per_ray(rr, variables)
  free = image_renderer.MIN_CHUNK * ray_bytes / image_renderer.MEMORY_SHARE
  device = image_renderer.make_image_renderer(rr, dataclasses.replace(settings, chunk=0),
                                              free_bytes=free)(variables)
  fixed = image_renderer.make_image_renderer(rr, dataclasses.replace(settings, chunk=256))(
      variables)
  assert (device.chunk, fixed.chunk) == (image_renderer.MIN_CHUNK, 256)
  pose = np.asarray(pose_spherical(30.0, -30.0, 4.0))
  rays = camera_rays(40, 40, (40.0, 40.0, 20.0, 20.0), pose, 2.0, 6.0, 0.5, False)
  bg = (1.0, 1.0, 1.0)
  a, b = device(rays, bg), fixed(rays, bg)
  assert a["rgb"].shape == (40, 40, 3)
  assert float(np.std(a["rgb"])) > 0  # not a blank image
  for k in ("rgb", "depth", "acc"):  # two compiled programs: equal within float32 rounding
    np.testing.assert_allclose(a[k], b[k], rtol=PATHS_RTOL, atol=1e-6)

