"""Scores over kept pixels (metrics' and lpips' mask argument, the evaluator with
Dataset.masks): PSNR against the definition, SSIM against a map computed by loops here and
averaged over the kept window centres by hand, LPIPS against its layer maps weighted here pixel
by pixel, and metrics.json's record of the masks."""

import dataclasses
import json

import numpy as np
import pytest

from nerf_jax.evaluate import evaluation, lpips, metrics
from nerf_jax.render import image_renderer
from nerf_jax.run import builders, experiment
from tests.helpers import requires_lpips, small_config


def _pair(height, width, seed=0):
  rng = np.random.default_rng(seed)
  a = rng.random((height, width, 3)).astype(np.float32)
  b = np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1).astype(np.float32)
  mask = (rng.random((height, width)) > 0.5).astype(np.float32)
  return a, b, mask


def _ssim_map_brute(x, y, size=11, sigma=1.5):
  """float64 [H - 10, W - 10]: SSIM of every valid window by loops, the mean over channels."""
  g = np.exp(-0.5 * ((np.arange(size) - (size - 1) / 2) / sigma) ** 2)
  w = np.outer(g, g) / np.sum(np.outer(g, g))
  c1, c2 = 0.01 ** 2, 0.03 ** 2
  out = np.zeros((x.shape[0] - size + 1, x.shape[1] - size + 1))
  for i in range(out.shape[0]):
    for j in range(out.shape[1]):
      for c in range(3):
        a = x[i:i + size, j:j + size, c].astype(np.float64)
        b = y[i:i + size, j:j + size, c].astype(np.float64)
        ma, mb = np.sum(w * a), np.sum(w * b)
        va, vb = np.sum(w * a * a) - ma ** 2, np.sum(w * b * b) - mb ** 2
        cov = np.sum(w * a * b) - ma * mb
        out[i, j] += (2 * ma * mb + c1) * (2 * cov + c2) / (
            3 * (ma ** 2 + mb ** 2 + c1) * (va + vb + c2))
  return out


def test_masked_psnr_is_over_kept_pixels():
  a, b, mask = _pair(9, 7)
  kept = mask > 0
  want = -10 * np.log10(np.mean((a[kept].astype(np.float64) - b[kept]) ** 2))
  np.testing.assert_allclose(metrics.psnr(a, b, mask), want, rtol=1e-5)
  np.testing.assert_allclose(metrics.psnr(a, b, np.ones((9, 7))), metrics.psnr(a, b), rtol=1e-6)
  assert np.isnan(metrics.psnr(a, b, np.zeros((9, 7))))


def test_masked_ssim_is_the_mean_of_its_map_over_kept_centres_counted_by_hand():
  a, b, mask = _pair(17, 15, seed=1)
  brute = _ssim_map_brute(a, b)
  total, count = 0.0, 0
  for i in range(brute.shape[0]):  # map position (i, j) is the window centred on (i+5, j+5)
    for j in range(brute.shape[1]):
      if mask[i + 5, j + 5]:
        total, count = total + brute[i, j], count + 1
  assert 0 < count < brute.size
  np.testing.assert_allclose(metrics.ssim_map(a, b), brute, atol=2e-5)
  np.testing.assert_allclose(metrics.ssim(a, b, mask), total / count, atol=2e-5)
  np.testing.assert_allclose(metrics.ssim(a, b, np.ones((17, 15))), metrics.ssim(a, b),
                             atol=1e-6)
  ring = np.ones((17, 15), np.float32)
  ring[5:12, 5:10] = 0.0  # every window centre masked: no SSIM
  assert np.isnan(metrics.ssim(a, b, ring))
  batch = metrics.ssim(np.stack([a, b]), np.stack([b, a]), np.stack([mask, mask]))
  np.testing.assert_allclose(batch, [metrics.ssim(a, b, mask)] * 2, rtol=1e-6)


def test_nearest_cells_average_the_pixels_each_cell_owns():
  table = lpips.nearest_cells(7, 3)  # pixels 0-2 -> cell 0, 3-4 -> 1, 5-6 -> 2
  np.testing.assert_allclose(table, [[1 / 3] * 3 + [0] * 4, [0] * 3 + [0.5] * 2 + [0] * 2,
                                     [0] * 5 + [0.5] * 2])


@requires_lpips
def test_masked_lpips_is_the_masked_mean_of_its_upsampled_map():
  a, b, _ = _pair(40, 36, seed=2)
  mask = np.ones((40, 36), np.float32)
  mask[5:30, 3:20] = 0.0
  params = lpips.load_params()
  maps = [np.asarray(m, np.float64) for m in lpips.layer_maps(2 * a - 1, 2 * b - 1, params)]
  want = 0.0
  for m in maps:  # each pixel votes for the cell nearest-neighbour upsampling gives it
    h, w = m.shape
    kept, owned = np.zeros((h, w)), np.zeros((h, w))
    for y in range(40):
      for x in range(36):
        cell = (y * h // 40, x * w // 36)
        owned[cell] += 1
        kept[cell] += mask[y, x]
    share = kept / owned
    want += np.sum(share * m) / np.sum(share)
  plain = sum(m.mean() for m in maps)  # the unmasked distance (layer_distances' sum)
  np.testing.assert_allclose(lpips.lpips(a, b, mask), want, rtol=1e-5)
  np.testing.assert_allclose(lpips.lpips(a, b, np.ones((40, 36))), plain, rtol=1e-5)
  assert not np.isclose(want, plain, rtol=1e-3)


def _grey(rays, background=None):
  """A stand-in image renderer's draw: grey rgb, so no NeRF needs compiling."""
  shape = rays.shape
  return {"rgb": np.full(shape + (3,), 0.5, np.float32), "depth": np.zeros(shape, np.float32),
          "acc": np.zeros(shape, np.float32)}


def test_evaluator_scores_kept_pixels_and_records_the_masks(monkeypatch, tmp_path):
  monkeypatch.setattr(image_renderer, "make_image_renderer", lambda *a: lambda p: _grey)
  exp = experiment.setup(small_config({"data.image_size": 16}))
  test = exp.test_ds
  masks = (np.random.default_rng(3).random(test.images.shape[:3]) > 0.3).astype(np.float32)
  exp = dataclasses.replace(exp, test_ds=dataclasses.replace(test, masks=masks))
  result = builders.make_evaluator(exp)({"params": {}}, max_views=2, out_dir=str(tmp_path))
  truths = exp.test_ds.images  # on black: the debug scene's background
  for k, view in enumerate(result["per_view"]):
    kept = masks[k] > 0
    want = -10 * np.log10(np.mean((truths[k][kept].astype(np.float64) - 0.5) ** 2))
    assert view["psnr"] == pytest.approx(want, rel=1e-5)
    assert view["ssim"] == pytest.approx(float(metrics.ssim(np.full_like(truths[k], 0.5),
                                                            truths[k], masks[k])), rel=1e-6)
  saved = json.loads((tmp_path / "metrics.json").read_text())
  assert saved["masks"] == evaluation.MASK_RULE
  assert saved["masked_pixels"] == pytest.approx(1.0 - masks[:2].mean(), rel=1e-6)
