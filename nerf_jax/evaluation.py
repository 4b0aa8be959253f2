"""Scoring a trained model on the test views: PSNR, SSIM, LPIPS and, where the data has them,
geometry scores (depth error, floaters); the evaluator used while training, by render.py and by
the benchmark.
"""

import json
import os

import imageio.v2 as imageio
import numpy as np

from nerf_jax import background, image_renderer, lpips, metrics, visuals


def make_evaluator(exp):
  """fn(variables, max_views=None, out_dir=None, on_view=None) -> {'psnr', 'ssim', 'lpips',
  'per_view'} (variables: a TrainState's, renderer.py); without LPIPS (the `lpips` extra missing, or
  images under 31 px a side) the 'lpips' keys are absent and 'lpips_skipped' says why in one line.
  Where the data has true opacity (and depth) the view means of `geometry_errors` come too:
  'empty_opacity', 'floaters' (and 'depth_error').

  Evaluates the test views of `exp` (an experiment.Experiment). With `out_dir`, writes per view
  a PNG of [prediction | depth | ground truth] and depth `.npy`. on_view(index, out, truth) is
  called for every view with the rendered numpy dict (rgb [H, W, 3], depth [H, W], acc [H, W])
  and the true image float32 [H, W, 3] on the configured background (see
  `background.images_on_background`; the trainer sends the first one to TensorBoard).
  """
  make_draw = image_renderer.make_image_renderer(exp.renderer, exp.image)
  bg = background.parse(exp.config.data.background)
  test_ds = exp.test_ds
  camera = (test_ds.height, test_ds.width, test_ds.intrinsics)
  truths = background.images_on_background(test_ds, bg)[1]
  lpips_skipped = lpips.unavailable_reason(test_ds.height, test_ds.width)  # None: LPIPS runs

  def evaluate(variables, max_views=None, out_dir=None, on_view=None):
    count = len(test_ds) if max_views is None else min(max_views, len(test_ds))
    per_view = []
    draw = make_draw(variables)
    for i in range(count):
      out = draw(exp.rays(test_ds.poses[i], camera), bg)
      truth = truths[i]
      view = {"view": i, "psnr": float(metrics.psnr(out["rgb"], truth)),
              "ssim": float(metrics.ssim(out["rgb"], truth)),
              **geometry_errors(out, test_ds, i)}
      if lpips_skipped is None:
        view["lpips"] = float(lpips.lpips(out["rgb"], truth))
      per_view.append(view)
      if on_view is not None:
        on_view(i, out, truth)
      if out_dir:
        _write_eval_view(out_dir, i, out, truth, exp.near, exp.far)
    names = dict.fromkeys(name for v in per_view for name in v if name != "view")
    result = {name: float(np.mean([v[name] for v in per_view if name in v])) for name in names}
    if lpips_skipped is not None:
      result["lpips_skipped"] = lpips_skipped
    result["per_view"] = per_view
    if out_dir:
      with open(os.path.join(out_dir, "metrics.json"), "w") as f:
        json.dump(result, f, indent=2)
    return result

  return evaluate


OPAQUE, EMPTY = 0.99, 0.01  # true opacity of pixels scored for depth, and of empty pixels


FLOATER_ACC = 0.1  # rendered opacity from which an empty pixel counts as showing a floater


GEOMETRY_SCORES = ("depth_error", "empty_opacity", "floaters")  # what geometry_errors gives


def geometry_errors(out, dataset, index):
  """Geometry scores of one rendered view where the data has them, {} otherwise.

  depth_error: median |depth - true depth| over pixels the truth covers (opacity > OPAQUE), in
  scene units (needs `dataset.depths`). empty_opacity: the mean rendered opacity over pixels
  the truth leaves empty (opacity < EMPTY); floaters: the fraction of those that render with
  opacity > FLOATER_ACC (need `dataset.accs`). out: the render's numpy dict (depth, acc [H, W]).
  """
  scores = {}
  if dataset.accs is None:
    return scores
  true_acc = dataset.accs[index]
  empty = true_acc < EMPTY
  if np.any(empty):
    scores["empty_opacity"] = float(np.mean(out["acc"][empty]))
    scores["floaters"] = float(np.mean(out["acc"][empty] > FLOATER_ACC))
  opaque = true_acc > OPAQUE
  if dataset.depths is not None and np.any(opaque):
    scores["depth_error"] = float(np.median(np.abs(out["depth"] - dataset.depths[index])[opaque]))
  return scores


def _write_eval_view(out_dir, index, out, truth, near, far):
  os.makedirs(out_dir, exist_ok=True)
  panel = np.concatenate([visuals.to_uint8(out["rgb"]), visuals.colorize(out["depth"], near, far),
                          visuals.to_uint8(truth)], axis=1)
  imageio.imwrite(os.path.join(out_dir, f"view_{index:03d}.png"), panel)
  np.save(os.path.join(out_dir, f"depth_{index:03d}.npy"), out["depth"].astype(np.float32))
