"""Tests of the built-in 'multiscale' scene (nerf_jax.data.scenes.multiscale): its views'
levels, cameras and distances, and each level's pixels as the mean of the full-size
rendering's pixels over their footprint."""

import numpy as np

from nerf_jax.data import scenes
from nerf_jax.data.scenes import multiscale, tracer
from tests.helpers import load_data

SIZE = 32


def test_views_cycle_through_the_levels_at_several_distances():
  ds = scenes.make_dataset("multiscale", num_views=8, height=SIZE, width=SIZE, focal=44.0)
  levels = np.arange(8) % multiscale.LEVELS
  assert [ds.cameras.camera(k) for k in range(2)] == [
      (32, 32, (44.0, 44.0, 16.0, 16.0)), (16, 16, (22.0, 22.0, 8.0, 8.0))]
  assert [a.shape[:2] for a in ds.images] == [(SIZE >> j,) * 2 for j in levels]
  np.testing.assert_array_equal(ds.lossmult, 4.0 ** levels)
  assert list(ds.labels) == [str(j) for j in levels]
  distance = np.linalg.norm(ds.poses[:, :3, 3], axis=-1)
  assert np.all(distance >= 4.0 - 1e-5) and np.all(distance <= 4.0 * (1 + multiscale.SPREAD))
  assert distance.max() - distance.min() > 1.0 and ds.far == 6.0 + 4.0 * multiscale.SPREAD
  for k in range(8):  # each camera looks at the origin
    forward = -ds.poses[k, :3, 2]
    np.testing.assert_allclose(forward, -ds.poses[k, :3, 3] / distance[k], atol=1e-5)


def test_a_levels_pixels_are_the_mean_of_the_full_size_pixels_they_cover():
  ds = scenes.make_dataset("multiscale", num_views=4, height=SIZE, width=SIZE, focal=44.0)
  for k in (1, 2):
    side = SIZE >> k
    full = tracer.render_images(multiscale.SCENE, ds.poses[k:k + 1], SIZE, SIZE, 44.0, 0.5,
                                ds.near, ds.far)["rgb"][0]
    box = full.reshape(side, SIZE // side, side, SIZE // side, 3).mean((1, 3))
    error = np.abs(ds.image(k) - box)
    assert error.mean() < 0.01 and np.abs(ds.image(k) - box.mean()).mean() > 5 * error.mean()


def test_the_scene_loads_by_name_and_splits_like_the_others():
  train, test = load_data({"scene": "multiscale", "num_views": 10, "image_size": 16})
  assert (len(train), len(test)) == (8, 2) and train.mixed_sizes
  assert set(train.labels) == {"0", "1", "2", "3"} and list(test.labels) == ["0", "1"]
