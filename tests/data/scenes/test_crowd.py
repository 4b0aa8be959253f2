"""Tests of the built-in `crowd` scene (scenes/occluders.py): passers-by in a share of the
training photos, each photo's look over the whole of it, and test views that are the static
scene's exact ground truth."""

import numpy as np

from nerf_jax.data import loaders, scenes
from nerf_jax.data.scenes import occluders, photos
from nerf_jax.run import builders

VIEWS, SIZE = 30, 24


def _load(scene):
  return loaders.load_dataset(builders.data_settings(
      {"scene": scene, "num_views": VIEWS, "image_size": SIZE}))


def test_crowd_is_the_static_scene_with_passers_by_in_a_share_of_the_photos():
  train, test = _load("crowd")
  clean_train, clean_test = scenes.make_dataset("diffuse", VIEWS, SIZE, SIZE).split()
  # The held-out views: the static scene alone, neutral look, exactly.
  np.testing.assert_array_equal(test.images, clean_test.images)
  crowded = occluders.crowded_views(len(train))
  assert crowded.sum() == round(occluders.SHARE * len(train))
  _, masks = occluders.with_crowd(clean_train)
  assert np.array_equal(masks.any(axis=(1, 2)), crowded)
  cover = masks[crowded].mean(axis=(1, 2))
  assert occluders.COVER[0] <= cover.mean() <= occluders.COVER[1]
  assert cover.min() > 0.5 * occluders.COVER[0] and cover.max() < 2 * occluders.COVER[1]
  # Everywhere else each photo is the static scene under its own gains.
  looks = photos.with_gains(clean_train.images, photos.gains(len(train)))
  np.testing.assert_array_equal(train.images[~masks], looks[~masks])
  assert np.abs(train.images[masks] - looks[masks]).max() > 0.1
  # A passer-by is opaque and stands in front of the scene.
  assert np.all(train.accs[masks] == 1.0)
  seen = masks & (clean_train.accs > 0)
  assert np.all(train.depths[seen] < clean_train.depths[seen])
