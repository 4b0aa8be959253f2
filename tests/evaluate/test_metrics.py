"""metrics.psnr / ssim against brute-force references written here."""

import numpy as np
import pytest

from nerf_jax.evaluate import metrics


def _ssim_brute(x, y, size=11, sigma=1.5):
  """SSIM with explicit loops over every valid window (Wang et al. 2004), mean over channels."""
  g = np.exp(-0.5 * ((np.arange(size) - (size - 1) / 2) / sigma) ** 2)
  w = np.outer(g, g) / np.sum(np.outer(g, g))
  c1, c2 = 0.01 ** 2, 0.03 ** 2
  vals = []
  for c in range(x.shape[-1]):
    for i in range(x.shape[0] - size + 1):
      for j in range(x.shape[1] - size + 1):
        a, b = x[i:i + size, j:j + size, c], y[i:i + size, j:j + size, c]
        ma, mb = np.sum(w * a), np.sum(w * b)
        va, vb = np.sum(w * a * a) - ma ** 2, np.sum(w * b * b) - mb ** 2
        cov = np.sum(w * a * b) - ma * mb
        vals.append((2 * ma * mb + c1) * (2 * cov + c2) / ((ma ** 2 + mb ** 2 + c1) * (va + vb + c2)))
  return np.mean(vals)


def test_psnr_matches_definition():
  rng = np.random.default_rng(0)
  a = rng.random((2, 8, 9, 3)).astype(np.float32)
  b = np.clip(a + 0.05 * rng.standard_normal(a.shape), 0, 1).astype(np.float32)
  expected = [-10 * np.log10(np.mean((a[i].astype(np.float64) - b[i]) ** 2)) for i in range(2)]
  np.testing.assert_allclose(metrics.psnr(a, b), expected, rtol=1e-5)


def test_psnr_of_identical_images_is_finite():
  a = np.ones((4, 4, 3), np.float32)
  assert metrics.psnr(a, a) == pytest.approx(100.0)


def test_ssim_matches_brute_force():
  rng = np.random.default_rng(1)
  x = rng.random((16, 14, 3)).astype(np.float32)
  y = np.clip(x + 0.1 * rng.standard_normal(x.shape), 0, 1).astype(np.float32)
  np.testing.assert_allclose(metrics.ssim(x, y), _ssim_brute(x, y), atol=2e-5)
  assert metrics.ssim(x, x) == pytest.approx(1.0, abs=1e-5)


def test_ssim_batches():
  rng = np.random.default_rng(2)
  x = rng.random((3, 12, 12, 3)).astype(np.float32)
  batch = metrics.ssim(x, x[::-1])
  single = [metrics.ssim(x[i], x[::-1][i]) for i in range(3)]
  np.testing.assert_allclose(batch, single, rtol=1e-6)
