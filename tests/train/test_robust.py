"""Tests of RobustNeRF's trimmed loss (train/losses/robust.py) against a brute-force mask and
trimmed mean written here, of its one switch (loss.robust.weight > 0: patch batches, the colour
term aside; run/builders.py) and of the patch batches it trains on (train/train_batches.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from nerf_jax.run import builders, experiment
from nerf_jax.train import losses, train_batches, train_step
from nerf_jax.train.losses import robust
from nerf_jax.train.state import TrainState
from tests.helpers import TINY_GRID, small_config

P = 8  # patch side


def _quantile_ref(values, q):
  """The q-quantile of values with linear interpolation between order statistics."""
  ordered = sorted(values)
  pos = q * (len(ordered) - 1)
  low = int(np.floor(pos))
  high = min(low + 1, len(ordered) - 1)
  return ordered[low] + (pos - low) * (ordered[high] - ordered[low])


def _mask_ref(residual, s):
  """RobustNeRF's mask one pixel at a time: residual float [n, P, P], s: Settings."""
  n, size, _ = residual.shape
  threshold = _quantile_ref(residual.reshape(-1).tolist(), s.inlier_quantile)
  inlier = residual < threshold
  half = s.filter_size // 2
  lower = (size - min(s.inner_size, size)) // 2
  mask = np.zeros_like(inlier)
  for k in range(n):
    patch_inlier = inlier[k].sum() / size ** 2 > s.patch_share
    for i in range(size):
      for j in range(size):
        count = sum(inlier[k, a, b] for a in range(i - half, i + half + 1)
                    for b in range(j - half, j + half + 1) if 0 <= a < size and 0 <= b < size)
        near = count / s.filter_size ** 2 > s.neighbour_share
        middle = (patch_inlier and lower <= i < lower + s.inner_size
                  and lower <= j < lower + s.inner_size)
        mask[k, i, j] = inlier[k, i, j] or near or middle
  return mask, threshold


def _patches(n=3, seed=0):
  """Residual-like patches: small noise, a square outlier blob in patch 0, lone outliers."""
  rng = np.random.default_rng(seed)
  residual = rng.uniform(0.0, 0.01, (n, P, P))
  residual[0, 1:7, 1:7] += 1.0  # an object: a cluster of large residuals
  residual[1, 4, 4] += 1.0  # fine detail: one pixel among inliers
  residual[2, 0, 7] += 1.0  # one at a corner (RobustNeRF's filter: zeros beyond the edge)
  return residual.astype(np.float32)


@pytest.mark.parametrize("fields", [
    {}, {"inlier_quantile": 0.5}, {"filter_size": 5, "neighbour_share": 0.3},
    {"inner_size": 4, "patch_share": 0.9}, {"inner_size": 12}])
def test_the_mask_matches_the_brute_force_rule(fields):
  settings = robust.Settings(weight=1.0, **fields)
  residual = _patches()
  mask, threshold = robust.inlier_mask(jnp.asarray(residual), settings)
  want, want_threshold = _mask_ref(residual, settings)
  np.testing.assert_allclose(threshold, want_threshold, rtol=1e-6)
  np.testing.assert_array_equal(np.asarray(mask), want)


def test_a_cluster_is_left_out_and_a_lone_outlier_kept():
  settings = robust.Settings(weight=1.0, inner_size=4)  # the patch's middle, as 8 of 16
  mask, _ = robust.inlier_mask(jnp.asarray(_patches()), settings)
  mask = np.asarray(mask)
  assert not mask[0, 2:6, 2:6].any()  # the object's inside
  assert mask[1, 4, 4]  # a lone outlier: its neighbours keep it
  assert not mask[2, 0, 7]  # ... but not at a corner, where 5 of its 9 are beyond the edge


def _inputs(passes, seed=0, weight=None):
  rng = np.random.default_rng(seed)
  target = rng.uniform(size=(3 * P * P, 3)).astype(np.float32)
  outputs = {}
  for k, name in enumerate(passes):
    rgb = target + rng.normal(0, 0.05, target.shape).astype(np.float32)
    rgb[: P * P].reshape(P, P, 3)[1:7, 1:7] += 0.8  # a passer-by in patch 0
    outputs[name] = {"rgb": jnp.asarray(rgb)}
  return losses.LossInputs(outputs, jnp.asarray(target), None, {},
                           None if weight is None else jnp.asarray(weight))


@pytest.mark.parametrize("passes", [("coarse",), ("coarse", "fine")])
@pytest.mark.parametrize("weighted", [False, True])
def test_the_loss_is_the_trimmed_mean_of_each_pass(passes, weighted):
  settings = robust.Settings(weight=0.7, inner_size=4)
  ray_weight = np.random.default_rng(5).uniform(0.5, 2.0, 3 * P * P).astype(np.float32)
  inputs = _inputs(passes, weight=ray_weight if weighted else None)
  loss, stats = robust.Robust(0.7, P, settings)(inputs)
  want = 0.0
  for name in passes:
    residual = np.mean((np.asarray(inputs.outputs[name]["rgb"]) - np.asarray(inputs.target))
                       ** 2, -1)
    mask, threshold = _mask_ref(residual.reshape(-1, P, P), settings)
    w = mask.reshape(-1) * (ray_weight if weighted else 1.0)
    want += sum(wi * ri for wi, ri in zip(w, residual)) / sum(w)
  np.testing.assert_allclose(loss, 0.7 * want, rtol=1e-5)
  np.testing.assert_allclose(stats["inliers"], mask.mean(), rtol=1e-6)
  np.testing.assert_allclose(stats["threshold"], threshold, rtol=1e-5)


def test_no_gradient_reaches_a_left_out_pixel():
  inputs = _inputs(("coarse",))
  term = robust.Robust(1.0, P, robust.Settings(weight=1.0, inner_size=4))
  rgb = inputs.outputs["coarse"]["rgb"]
  grad = jax.grad(lambda c: term(inputs.replace(outputs={"coarse": {"rgb": c}}))[0])(rgb)
  grad = np.asarray(grad)[: P * P].reshape(P, P, 3)
  assert np.all(grad[2:6, 2:6] == 0) and np.any(grad[7] != 0)


def test_settings_that_cannot_work_name_the_field():
  with pytest.raises(ValueError, match="config.loss.robust.inlier_quantile=0"):
    robust.Settings(inlier_quantile=0.0)
  with pytest.raises(ValueError, match="config.loss.robust.filter_size=2"):
    robust.Settings(filter_size=2)
  with pytest.raises(ValueError, match="config.loss.robust.weight=-1"):
    robust.Settings(weight=-1.0)


def _terms(**fields):
  config = small_config(**fields)
  return builders.loss_terms(config, builders.make_ray_renderer(config))


# RobustNeRF on, spelt with the switch alone and with the four settings it took before.
SWITCH = {"loss.robust.weight": 1.0}
FOUR = {"train.batching": "patches", "train.patch_size": 16, "loss.colour.weight": 0.0,
        "loss.robust.weight": 1.0}


def test_the_switch_alone_trains_on_patches_without_the_colour_loss():
  assert [t.name for t in _terms()] == ["colour"]  # off by default
  config = small_config(**SWITCH, **{"train.patch_size": 4})
  assert config.train.batching == "rays" and config.loss.colour.weight == 1.0  # untouched
  batch = builders.batch_settings(config)
  assert (batch.batching, batch.patch_size) == ("patches", 4)
  terms = _terms(**SWITCH, **{"train.patch_size": 4})
  assert [t.name for t in terms] == ["colour", "robust"]
  assert terms[0].weight == 0.0 and terms[1].patch_size == 4  # the colour term steps aside
  # 'patches' spelt out is the same; the four old settings give the same batches and terms.
  assert _terms(**SWITCH, **{"train.batching": "patches", "train.patch_size": 4}) == terms
  assert _terms(**FOUR) == _terms(**SWITCH)
  assert (builders.batch_settings(small_config(**FOUR))
          == builders.batch_settings(small_config(**SWITCH)))


@pytest.mark.parametrize("passes", [("coarse",), ("coarse", "fine")])
def test_the_total_is_the_trimmed_loss_alone(passes):
  # Whatever loss.colour.weight and coarse_weight say, the colour term adds nothing: the total
  # is the trimmed mean of each pass (the brute-force mask), the colour term's PSNR still logged.
  terms = _terms(**SWITCH, **{"train.patch_size": P, "loss.colour.coarse_weight": 0.5,
                              "loss.robust.inner_size": 4})
  inputs = _inputs(passes)
  total, stats = losses.total(terms, inputs)
  want = 0.0
  for name in passes:
    residual = np.mean((np.asarray(inputs.outputs[name]["rgb"]) - np.asarray(inputs.target))
                       ** 2, -1)
    mask, _ = _mask_ref(residual.reshape(-1, P, P), terms[1].settings)
    want += residual[mask.reshape(-1)].mean()
  np.testing.assert_allclose(total, want, rtol=1e-5)
  assert total == terms[1](inputs)[0]  # exactly the robust term's
  plain = terms[0].__class__(weight=1.0, coarse_weight=0.5)(inputs)[0]
  assert abs(float(plain) - want) > 0.01  # the colour loss would have shown
  assert set(stats) == {"loss", "colour/psnr", "robust/inliers", "robust/threshold"}


def test_whole_images_contradict_the_switch():
  config = small_config(**SWITCH, **{"train.batching": "images"})
  match = r"config.train.batching='images' contradicts config.loss.robust.weight=1.0"
  with pytest.raises(ValueError, match=match):
    builders.batch_settings(config)
  with pytest.raises(ValueError, match=match):
    _terms(**SWITCH, **{"train.batching": "images"})
  # Off, whole images are whole images; and a term built without patches still refuses.
  assert builders.batch_settings(small_config(**{"train.batching": "images"})).batching == (
      "images")
  with pytest.raises(ValueError, match="config.loss.robust.weight > 0 needs patches"):
    robust.build(robust.Settings(weight=1.0), losses.Context(None))


def test_the_switch_without_its_term_is_one_line():
  terms = ("colour", "distortion")  # robust left out: patches with the colour loss alone
  with pytest.raises(ValueError, match=r"config.loss.robust.weight=1.0 needs 'robust' in "
                                       r"config.loss.terms"):
    _terms(**SWITCH, **{"loss.terms": terms})


def _two_steps(fields):
  """(stats of each step, final params) of two Adam steps of a tiny crowd run with `fields`."""
  config = small_config(TINY_GRID, base="scenes/crowd", **{
      "train.batch_rays": 64, "num_samples": 8, "train.remat_chunk": 0, **fields})
  exp = experiment.setup(config)
  ray_renderer = builders.training_renderer(exp)
  tx = optax.adam(1e-2)
  step = train_step.make_train_step(ray_renderer, tx, builders.loss_terms(config, ray_renderer),
                                    builders.step_settings(exp))
  params = ray_renderer.init(jax.random.PRNGKey(0))["params"]
  state = TrainState(step=jnp.int32(0), params=params, opt_state=tx.init(params),
                     bad_step=jnp.int32(-1), buffers={}, ema={})
  data = builders.make_train_data(exp)
  history = []
  for _ in range(2):
    state, stats = step(state, data, jax.random.PRNGKey(3))
    history.append({k: np.asarray(v) for k, v in stats.items()})
  return history, jax.tree_util.tree_map(np.asarray, state.params)


def test_the_four_old_settings_train_bit_identically_to_the_switch():
  old = _two_steps({**FOUR, "train.patch_size": 4})
  new = _two_steps({"loss.robust.weight": 1.0, "train.patch_size": 4})
  assert old[0][0].keys() == new[0][0].keys() and "robust/inliers" in new[0][0]
  for before, after in zip(old[0], new[0]):
    for key in before:
      np.testing.assert_array_equal(before[key], after[key], err_msg=key)
  jax.tree_util.tree_map(np.testing.assert_array_equal, old[1], new[1])


def test_patch_batches_are_whole_patches_of_one_image():
  rng = np.random.default_rng(0)
  num, height, width, size = 3, 10, 12, 4
  colours = rng.uniform(size=(num, height, width, 3)).astype(np.float32)
  data = train_batches.TrainData(
      rays=None, rgb=jnp.asarray(colours.reshape(num, -1, 3)),
      acc=jnp.ones((num, height * width)), poses=jnp.tile(jnp.eye(4), (num, 1, 1)),
      camera=(height, width, (10.0, 10.0, 6.0, 5.0), 2.0, 6.0, 0.5, False))
  settings = train_batches.BatchSettings(batching="patches", batch_rays=50, patch_size=size)
  assert settings.num_patches() == 3
  assert train_batches.rays_per_step(settings, height, width) == 3 * size * size
  draw = jax.jit(lambda key: train_batches.draw_batch(data, settings, key))
  corners = set()
  for seed in range(20):
    batch = draw(jax.random.PRNGKey(seed))
    image = np.asarray(batch.image).reshape(-1, size, size)
    pixel = np.asarray(batch.pixel).reshape(-1, size, size)
    for k in range(3):
      assert np.all(image[k] == image[k, 0, 0])
      row, col = divmod(int(pixel[k, 0, 0]), width)
      assert row + size <= height and col + size <= width
      corners.add((row, col))
      want = colours[image[k, 0, 0], row:row + size, col:col + size]
      np.testing.assert_array_equal(np.asarray(batch.rgb).reshape(-1, size, size, 3)[k], want)
  assert len(corners) > 20  # corners are drawn, not fixed
  with pytest.raises(ValueError, match="config.train.patch_size=11"):
    train_batches.draw_batch(data, train_batches.BatchSettings(batching="patches",
                                                               patch_size=11),
                             jax.random.PRNGKey(0))


def test_a_patchs_masked_pixels_weigh_nothing():
  num, height, width, size = 2, 8, 8, 4
  mask = np.random.default_rng(1).uniform(size=(num, height * width)) > 0.3
  data = train_batches.TrainData(
      rays=None, rgb=jnp.zeros((num, height * width, 3)), acc=jnp.ones((num, height * width)),
      poses=jnp.tile(jnp.eye(4), (num, 1, 1)),
      camera=(height, width, (8.0, 8.0, 4.0, 4.0), 2.0, 6.0, 0.5, False),
      mask=jnp.asarray(mask, jnp.float32))
  settings = train_batches.BatchSettings(batching="patches", batch_rays=32, patch_size=size)
  batch = train_batches.draw_batch(data, settings, jax.random.PRNGKey(3))
  want = mask[np.asarray(batch.image), np.asarray(batch.pixel)]
  np.testing.assert_array_equal(np.asarray(batch.weight), want.astype(np.float32))
