"""The warm-up's shrunk photos against a box mean written here (run/auto/warm_up.py)."""

import numpy as np

from nerf_jax.data.dataset import Dataset
from nerf_jax.run.auto import warm_up


def test_box_shrunk_is_the_box_mean_of_the_cropped_photos():
  rng = np.random.default_rng(0)
  images = rng.uniform(size=(2, 10, 7, 3)).astype(np.float32)
  masks = np.ones((2, 10, 7), np.float32)
  masks[0, 4, 1] = 0.0  # one masked pixel drops its whole box
  poses = np.tile(np.eye(4, dtype=np.float32), (2, 1, 1))
  data = Dataset(images, poses, (8.0, 9.0, 3.5, 5.0), masks=masks)
  small = warm_up.box_shrunk(data, 4)  # factor ceil(10 / 4) = 3: 3 x 2 boxes, a row cropped
  assert small.images.shape == (2, 3, 2, 3)
  for n in range(2):
    for i in range(3):
      for j in range(2):
        box = images[n, 3 * i:3 * i + 3, 3 * j:3 * j + 3]
        np.testing.assert_allclose(small.images[n, i, j], box.mean(axis=(0, 1)), rtol=1e-6)
  want = np.ones((2, 3, 2), np.float32)
  want[0, 1, 0] = 0.0
  np.testing.assert_array_equal(small.masks, want)
  assert small.intrinsics == (8.0 / 3, 3.0, 3.5 / 3, 5.0 / 3)
  assert warm_up.box_shrunk(data, 10).images.shape == images.shape  # already small enough


def test_masked_pixels_leave_no_residual(monkeypatch):
  # A masked pixel was never trained on: the warm-up's render there is the photo itself, so
  # transients.transient_share sees no residual in it (a user's mask is not a passer-by).
  monkeypatch.setattr(warm_up, "WARM_UP_STEPS", 2)
  rng = np.random.default_rng(1)
  images = rng.uniform(size=(4, 12, 12, 3)).astype(np.float32)
  poses = np.tile(np.eye(4, dtype=np.float32), (4, 1, 1))
  poses[:, 2, 3] = np.arange(4.0, 8.0)
  masks = np.ones((4, 12, 12), np.float32)
  masks[:, :5, :5] = 0.0
  data = Dataset(images, poses, (12.0, 12.0, 6.0, 6.0), masks=masks)
  photos, renders = warm_up.photos_and_renders(data)
  assert photos.shape == renders.shape == (4, 12, 12, 3)
  np.testing.assert_array_equal(renders[:, :5, :5], photos[:, :5, :5])
  assert np.abs(renders - photos)[:, 6:, 6:].max() > 0  # elsewhere the field's own render
