"""eval.appearance='left_half' (NeRF-W's protocol): the code fitted on a test image's left half
is the least-squares optimum, found in closed form here for a field whose colour is linear in
the code; the right half's pixels never reach the fit, and are what is scored."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.evaluate import evaluation
from nerf_jax.render import image_renderer
from nerf_jax.run import builders, experiment
from tests.helpers import small_config

H, W, D = 8, 12, 3  # image height, width; code length


class LinearField:
  """A ray renderer whose colour is linear in the appearance code: rgb = base + a @ code, with
  per-ray `base` float32 [..., 3] and `a` float32 [..., 3, D] carried by the rays (a dict)."""

  def render(self, variables, rays, background=None):
    del background  # nothing is composited: the colour is the field's
    code = variables["params"]["field"]["appearance"][0]  # every row is the code (with_codes)
    return {"coarse": {"rgb": rays["base"] + jnp.einsum("...cd,d->...c", rays["a"], code)}}


def _view(seed):
  """(rays {base [H, W, 3], a [H, W, 3, D]}, truth float32 [H, W, 3], variables)."""
  k = jax.random.split(jax.random.PRNGKey(seed), 4)
  rays = {"base": jax.random.uniform(k[0], (H, W, 3)),
          "a": jax.random.normal(k[1], (H, W, 3, D))}
  truth = jax.random.uniform(k[2], (H, W, 3))  # no code explains it exactly: a least squares
  table = jax.random.normal(k[3], (5, D))  # the training codes; the fit starts at their mean
  return rays, np.asarray(truth), {"params": {"field": {"appearance": table}}}


def _fit(rays, truth, variables, steps=1000, mask=None, decay_every=333):
  """The code fitted on the left half; mask: float32 [H, W] or None, as evaluate passes it."""
  settings = evaluation.Settings(appearance="left_half", fit_steps=steps, fit_rays=4096,
                                 fit_lr=1e-2, fit_decay_every=decay_every)
  fit = evaluation.make_code_fitter(LinearField(), settings)
  weight = None if mask is None else jnp.asarray(evaluation.left_half_mask(mask))
  fitted = fit(variables, *evaluation.left_half(rays, truth), jnp.zeros(3), weight)
  return np.asarray(fitted["params"]["field"]["appearance"][0])


def _least_squares(rays, truth, kept=None):
  """The code minimising the squared error over the left half's pixels (columns < W // 2),
  by the normal equations, in float64; kept: bool [H, W] or None, the pixels that count."""
  kept = np.ones((H, W), bool) if kept is None else kept
  a = np.asarray(rays["a"], np.float64)[:, :W // 2][kept[:, :W // 2]].reshape(-1, D)
  r = (truth - np.asarray(rays["base"]))[:, :W // 2][kept[:, :W // 2]].reshape(-1)
  return np.linalg.solve(a.T @ a, a.T @ r)


def test_the_fitted_code_is_the_left_halfs_least_squares_optimum():
  rays, truth, variables = _view(0)
  optimum = _least_squares(rays, truth)
  start = np.asarray(variables["params"]["field"]["appearance"]).mean(0)
  assert np.abs(start - optimum).max() > 0.3  # the fit has somewhere to go
  # Rays drawn with replacement weigh the pixels unevenly each step; the protocol's 1000 Adam
  # steps, their size x0.1 every 333, settle within a thousandth of the optimum.
  np.testing.assert_allclose(_fit(rays, truth, variables), optimum, atol=0.005)
  # The former default, 100 steps of a constant 1e-2, stopped short of it.
  assert np.abs(_fit(rays, truth, variables, 100, decay_every=0) - optimum).max() > 0.1


def test_the_default_fit_is_nerfbaselines_nerfw_protocol():
  settings = evaluation.Settings()
  assert (settings.fit_steps, settings.fit_decay_every, settings.fit_lr) == (1000, 333, 1e-2)
  schedule = evaluation.fit_schedule(settings)
  np.testing.assert_allclose([schedule(k) for k in (0, 332, 333, 665, 666, 999)],
                             [1e-2, 1e-2, 1e-3, 1e-3, 1e-4, 1e-5], rtol=1e-5)
  assert evaluation.fit_schedule(dataclasses.replace(settings, fit_decay_every=0)) == 1e-2


def test_a_masked_fit_is_the_kept_pixels_optimum_not_all_pixels():
  """Masked pixels of the left half painted with a colour that a code 2 away in every entry
  explains: fitted with the mask (as evaluate passes it, evaluation.left_half_mask), the code
  is the least-squares optimum over the kept pixels alone, far from the one over every pixel."""
  rays, truth, variables = _view(3)
  rng = np.random.default_rng(3)
  kept = rng.uniform(size=(H, W)) > 0.3
  kept[:, W // 2:] = True  # the right half: scored, never fitted on
  optimum = _least_squares(rays, truth, kept)
  pulled = np.asarray(rays["base"]) + np.einsum("hwcd,d->hwc", np.asarray(rays["a"]),
                                                optimum + 2.0)
  truth = np.where(kept[..., None], truth, pulled).astype(np.float32)
  every_pixel = _least_squares(rays, truth)
  assert np.abs(every_pixel - optimum).max() > 0.1  # the masked pixels would pull the fit
  got = _fit(rays, truth, variables, mask=kept.astype(np.float32))
  np.testing.assert_allclose(got, optimum, atol=0.005)


def test_the_right_half_never_reaches_the_fit_and_is_what_is_scored():
  rays, truth, variables = _view(1)
  other = truth.copy()
  other[:, W // 2:] = np.random.default_rng(0).uniform(size=other[:, W // 2:].shape)
  code, same = _fit(rays, truth, variables, 50), _fit(rays, other, variables, 50)
  np.testing.assert_array_equal(code, same)
  # What is scored: the columns the fit did not see.
  np.testing.assert_array_equal(evaluation.right_half(truth), truth[:, W // 2:])
  assert evaluation.right_half(np.zeros((H, W + 1, 3))).shape == (H, W + 1 - W // 2, 3)


def test_the_left_half_is_the_columns_before_the_middle():
  rays, truth, _ = _view(2)
  left, target = evaluation.left_half(rays, truth)
  np.testing.assert_array_equal(target, truth[:, :W // 2].reshape(-1, 3))
  np.testing.assert_array_equal(left["a"], np.asarray(rays["a"])[:, :W // 2].reshape(-1, 3, D))


def _grey(rays, background=None):
  """A stand-in image renderer's draw: grey rgb, so no NeRF needs compiling."""
  del background
  shape = rays.shape
  return {"rgb": np.full(shape + (3,), 0.5, np.float32), "depth": np.zeros(shape, np.float32),
          "acc": np.zeros(shape, np.float32)}


def test_the_evaluator_fits_each_view_on_its_left_halfs_kept_pixels(monkeypatch):
  """evaluate hands the fitter each test view's left-half pixels and, with Dataset.masks, the
  left half of that view's mask as the weight, pixel for pixel (the fitter itself: above)."""
  calls = []

  def recording_fitter(ray_renderer, settings):
    def fit(variables, rays, target, bg, weight=None):
      calls.append((np.asarray(target), None if weight is None else np.asarray(weight)))
      return variables
    return fit
  monkeypatch.setattr(image_renderer, "make_image_renderer", lambda *a: lambda p: _grey)
  monkeypatch.setattr(evaluation, "make_code_fitter", recording_fitter)
  config = small_config({"data.image_size": 24, "model.appearance_dims": 4,  # SSIM: >= 11 wide
                         "eval.appearance": "left_half"})
  exp = experiment.setup(config)
  test = exp.test_ds
  masks = (np.random.default_rng(4).random(test.images.shape[:3]) > 0.3).astype(np.float32)
  exp = dataclasses.replace(exp, test_ds=dataclasses.replace(test, masks=masks))
  builders.make_evaluator(exp)({"params": {}}, max_views=2)
  assert len(calls) == 2
  for k, (target, weight) in enumerate(calls):
    left = slice(0, test.images.shape[2] // 2)
    np.testing.assert_array_equal(target, test.images[k][:, left].reshape(-1, 3))
    np.testing.assert_array_equal(weight, masks[k][:, left].reshape(-1))


def test_a_view_whose_left_half_is_all_masked_keeps_the_mean_code(monkeypatch, capsys):
  """A view with no kept pixel on its left half has nothing to fit a code on (the fit would
  draw its rays with zero weights: masked pixels): the evaluator renders it with the mean code
  (the variables as given), flags it in its per-view scores and says so; the other views are
  fitted as before."""
  fitted, drawn = [], []

  def recording_fitter(ray_renderer, settings):
    def fit(variables, rays, target, bg, weight=None):
      fitted.append(np.asarray(target))
      return {"fitted": True}
    return fit
  monkeypatch.setattr(image_renderer, "make_image_renderer",
                      lambda *a: lambda p: drawn.append(p) or _grey)
  monkeypatch.setattr(evaluation, "make_code_fitter", recording_fitter)
  config = small_config({"data.image_size": 24, "model.appearance_dims": 4,
                         "eval.appearance": "left_half"})
  exp = experiment.setup(config)
  test = exp.test_ds
  masks = np.ones(test.images.shape[:3], np.float32)
  masks[0, :, :test.images.shape[2] // 2] = 0.0  # view 0: its left half all masked
  exp = dataclasses.replace(exp, test_ds=dataclasses.replace(test, masks=masks))
  variables = {"params": {}}
  result = builders.make_evaluator(exp)(variables, max_views=2)
  assert len(fitted) == 1  # view 1 alone
  np.testing.assert_array_equal(fitted[0], test.images[1][:, :test.images.shape[2] // 2]
                                .reshape(-1, 3))
  assert drawn[1:] == [variables, {"fitted": True}]  # view 0 drawn with the mean code
  assert result["per_view"][0]["mean_code"] is True and "mean_code" not in result["per_view"][1]
  assert "mean_code" not in result
  assert "eval: view 0 keeps no pixel of its left half" in capsys.readouterr().out
