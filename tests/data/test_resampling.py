"""The data layer's resampling (data/resampling.py) against loops written out here."""

import numpy as np
import pytest

from nerf_jax.data import resampling


def _bilinear_loop(image, row, column):
  """`image` [h, w, C] at one continuous index (row, column) inside it, written out."""
  i, j = int(row), int(column)
  fr, fc = row - i, column - j
  i1, j1 = min(i + 1, image.shape[0] - 1), min(j + 1, image.shape[1] - 1)
  return ((1 - fr) * (1 - fc) * image[i, j] + (1 - fr) * fc * image[i, j1]
          + fr * (1 - fc) * image[i1, j] + fr * fc * image[i1, j1])


def test_bilinear_against_a_loop():
  rng = np.random.default_rng(2)
  image = rng.uniform(0, 1, (5, 7, 3))
  rows, columns = rng.uniform(0, 4, 40), rng.uniform(0, 6, 40)
  got = resampling.bilinear(image, rows, columns)
  assert got.shape == (40, 3) and got.dtype == np.float64
  for row, column, value in zip(rows, columns, got):
    np.testing.assert_allclose(value, _bilinear_loop(image, row, column), atol=1e-12)


def test_bilinear_on_a_grid_is_each_point_and_keeps_float32():
  rng = np.random.default_rng(3)
  image = rng.uniform(0, 1, (6, 9, 2)).astype(np.float32)
  rows, columns = rng.uniform(0, 5, 4), rng.uniform(0, 8, 3)
  grid = resampling.bilinear(image, rows[:, None], columns[None, :])
  assert grid.shape == (4, 3, 2) and grid.dtype == np.float32
  for a, row in enumerate(rows):
    for b, column in enumerate(columns):
      np.testing.assert_allclose(grid[a, b], _bilinear_loop(image.astype(np.float64), row,
                                                            column), atol=1e-6)


@pytest.mark.parametrize("height,width", [(5, 7), (1, 4), (3, 1)])
def test_bilinear_beyond_the_border_is_the_nearest_edge_pixel(height, width):
  image = np.random.default_rng(4).uniform(0, 1, (height, width, 3))
  rows = np.array([-3.0, -3.0, height + 2.0, height + 2.0])
  columns = np.array([-1.5, width + 4.0, -1.5, width + 4.0])
  want = image[[0, 0, height - 1, height - 1], [0, width - 1, 0, width - 1]]
  np.testing.assert_allclose(resampling.bilinear(image, rows, columns), want, atol=1e-12)
  # Pixel centres give the pixels back.
  r, c = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
  np.testing.assert_allclose(resampling.bilinear(image, r.astype(float), c.astype(float)),
                             image, atol=1e-12)


@pytest.mark.parametrize("factor", [1, 2, 3])
def test_block_mean_against_a_loop(factor):
  images = np.random.default_rng(5).uniform(0, 1, (2, 7, 8, 3))  # partial blocks at 2 and 3
  got = resampling.block_mean(images, factor)
  assert got.shape == (2, 7 // factor, 8 // factor, 3)
  for n, i, j in np.ndindex(got.shape[:3]):
    block = images[n, i * factor:(i + 1) * factor, j * factor:(j + 1) * factor]
    np.testing.assert_allclose(got[n, i, j], block.reshape(-1, 3).mean(0), atol=1e-12)
  # One image [H, W, C] alike, in its own dtype.
  one = resampling.block_mean(images[1].astype(np.float32), factor)
  assert one.dtype == np.float32
  np.testing.assert_allclose(one, got[1], atol=1e-6)
