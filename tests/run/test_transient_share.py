"""Tests of run/auto/transient_share.py's statistic: the box shares against a loop, each photo's look
taken out exactly, and the statistic on made-up photos: near 0 for a static scene with edges,
specks and looks, about the passers-by's share with them."""

import numpy as np

from nerf_jax.run.auto import transient_share


def test_box_share_counts_each_box_with_zeros_beyond_the_edge():
  mask = np.random.default_rng(0).uniform(size=(2, 7, 9)) > 0.5
  got = transient_share.box_share(mask, 3)
  for n, i, j in np.ndindex(mask.shape):
    count = sum(mask[n, a, b] for a in range(i - 1, i + 2) for b in range(j - 1, j + 2)
                if 0 <= a < 7 and 0 <= b < 9)
    assert abs(got[n, i, j] - count / 9) < 1e-12


def test_a_photos_own_gain_is_no_residual():
  rng = np.random.default_rng(1)
  renders = rng.uniform(size=(3, 8, 8, 3))
  gains = rng.uniform(0.5, 1.5, (3, 1, 1, 3))
  np.testing.assert_allclose(transient_share.residuals(gains * renders, renders), 0.0, atol=1e-20)


def _photos(with_crowd, seed=0):
  """(photos, renders) of 20 photos of 32 x 32: smooth renders, photos off by a little noise,
  a blurred edge (a column off in every photo), specks, each photo's own gain; with_crowd: a
  12 x 12 square of a saturated colour in half of the photos (14% of their pixels)."""
  rng = np.random.default_rng(seed)
  ramp = np.linspace(0.3, 0.7, 32)
  renders = np.broadcast_to(0.5 * (ramp[:, None, None] + ramp[None, :, None]), (20, 32, 32, 3))
  photos = renders + rng.normal(0, 0.02, renders.shape)
  photos[:, :, 16] += 0.3  # an edge the warm-up has not sharpened, in every photo
  specks = rng.uniform(size=(20, 32, 32)) < 0.01
  photos[specks] += 0.5
  if with_crowd:
    for n in range(0, 20, 2):
      y, x = rng.integers(0, 20, 2)
      photos[n, y:y + 12, x:x + 12] = rng.permutation([0.95, 0.05, 0.5])
  return photos * rng.uniform(0.6, 1.4, (20, 1, 1, 3)), renders


def test_the_statistic_tells_a_crowd_from_a_static_scene():
  static, _ = transient_share.transient_share(*_photos(False))
  crowd, shares = transient_share.transient_share(*_photos(True))
  assert static < 0.005
  assert 0.03 < crowd < 0.1  # half the photos, ~14 % each (the squares' edges blur a little)
  assert np.all(shares[1::2] < 0.005)  # the photos without passers-by
  assert np.sum(shares[::2] > 0.05) >= 8  # with them (a colour near the photo's: less)
