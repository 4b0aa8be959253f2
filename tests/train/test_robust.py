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
from nerf_jax.train.losses import colour, robust
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


def _mask_ref(residual, s, kept=None):
  """RobustNeRF's mask one pixel at a time: residual float [n, P, P], s: Settings, kept: bool
  [n, P, P] or None (all kept). A masked pixel is in no statistic: the quantile is over the
  kept residuals, a box's share over its kept pixels and the cells beyond the edge, a patch's
  vote over its kept pixels; it is never in the mask."""
  n, size, _ = residual.shape
  kept = np.ones(residual.shape, bool) if kept is None else kept
  threshold = _quantile_ref(residual[kept].tolist(), s.inlier_quantile)
  inlier = (residual < threshold) & kept
  half = s.filter_size // 2
  lower = (size - min(s.inner_size, size)) // 2
  near = np.zeros_like(inlier)
  for k in range(n):
    for i in range(size):
      for j in range(size):
        box = [(a, b) for a in range(i - half, i + half + 1)
               for b in range(j - half, j + half + 1)]
        inside = [(a, b) for a, b in box if 0 <= a < size and 0 <= b < size]
        count = sum(inlier[k, a, b] for a, b in inside)
        cells = len(box) - sum(not kept[k, a, b] for a, b in inside)  # edge cells count
        near[k, i, j] = count / cells > s.neighbour_share
  mask = np.zeros_like(inlier)
  for k in range(n):
    voters = [(inlier[k, i, j] or (s.dilate and near[k, i, j]))
              for i in range(size) for j in range(size) if kept[k, i, j]]
    patch_inlier = bool(voters) and sum(voters) / len(voters) > s.patch_share
    for i in range(size):
      for j in range(size):
        middle = (patch_inlier and lower <= i < lower + s.inner_size
                  and lower <= j < lower + s.inner_size)
        mask[k, i, j] = kept[k, i, j] and (inlier[k, i, j] or near[k, i, j] or middle)
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


def _lattice_patches():
  """_patches and five more: patch 3 has 40% outliers on a diagonal lattice (each with 5 of its
  9 box cells inliers), so that its raw inliers (60%) lose the patch vote and its inliers
  dilated by the box rule win it; the rest small noise."""
  rng = np.random.default_rng(7)
  residual = np.concatenate([_patches(), rng.uniform(0.0, 0.01, (5, P, P))])
  i, j = np.meshgrid(np.arange(P), np.arange(P), indexing="ij")
  residual[3][np.isin((i + j) % 5, (0, 2))] += 1.0
  return residual.astype(np.float32)


def _masked(residual, share=0.45, seed=3):
  """(residual, kept): `share` of the pixels masked, at random, with the large residuals of a
  masked pixel (its target black: the render's own colour), 0.2-1.5 (between the inliers' and
  above the outliers')."""
  rng = np.random.default_rng(seed)
  kept = rng.uniform(size=residual.shape) > share
  residual = np.where(kept, residual, rng.uniform(0.2, 1.5, residual.shape))
  return residual.astype(np.float32), kept


@pytest.mark.parametrize("masks", [False, True])
@pytest.mark.parametrize("fields", [
    {}, {"dilate": True}, {"inlier_quantile": 0.5}, {"filter_size": 5, "dilate": True},
    {"inner_size": 4, "patch_share": 0.9}])
def test_the_mask_over_kept_pixels_matches_the_brute_force_rule(fields, masks):
  settings = robust.Settings(weight=1.0, **fields)
  residual, kept = _lattice_patches(), None
  if masks:
    residual, kept = _masked(residual)
  mask, threshold = jax.jit(lambda r, k: robust.inlier_mask(r, settings, k))(
      jnp.asarray(residual), None if kept is None else jnp.asarray(kept))
  want, want_threshold = _mask_ref(residual, settings, kept)
  np.testing.assert_allclose(threshold, want_threshold, rtol=1e-6)
  np.testing.assert_array_equal(np.asarray(mask), want)


def test_dilation_decides_the_lattice_patchs_vote():
  residual = _lattice_patches()
  plain = np.asarray(robust.inlier_mask(jnp.asarray(residual), robust.Settings())[0])
  dilated = np.asarray(robust.inlier_mask(jnp.asarray(residual),
                                          robust.Settings(dilate=True))[0])
  middle = np.asarray(robust.inner_square(P, 8))  # the whole patch: inner_size 8
  assert not plain[3].all() and dilated[3][middle].all()
  np.testing.assert_array_equal(np.delete(plain, 3, 0), np.delete(dilated, 3, 0))


def test_masked_pixels_do_not_move_the_threshold():
  # Half the batch masked, each masked pixel's residual large (a black target): over all
  # pixels the 0.8 quantile falls among the masked ones and the passer-by (patch 0's blob)
  # would be kept; over the kept pixels it is trimmed.
  residual, kept = _masked(_patches(6), share=0.5)
  residual[0, 1:7, 1:7] = 0.15  # the passer-by, smaller than a masked pixel's residual
  kept[0, 1:7, 1:7] = True
  settings = robust.Settings(inner_size=4)
  mask, threshold = robust.inlier_mask(jnp.asarray(residual), settings, jnp.asarray(kept))
  assert float(threshold) < 0.15 and not np.asarray(mask)[0, 2:6, 2:6].any()
  everything, all_threshold = robust.inlier_mask(jnp.asarray(residual), settings)
  assert float(all_threshold) > 0.15 and np.asarray(everything)[0, 2:6, 2:6].all()


@pytest.mark.parametrize("dilate", [False, True])
def test_no_masked_pixel_changes_nothing_bit_for_bit(dilate):
  # A mask that keeps every pixel gives the very bits of no mask: threshold, mask and loss.
  settings = robust.Settings(weight=1.0, inner_size=4, dilate=dilate)
  residual = jnp.asarray(_lattice_patches())
  rule = jax.jit(lambda r, k: robust.inlier_mask(r, settings, k))
  without, with_ = rule(residual, None), rule(residual, jnp.ones(residual.shape, bool))
  np.testing.assert_array_equal(without[0], with_[0])
  assert without[1].tobytes() == with_[1].tobytes()
  term = robust.Robust(1.0, P, settings)
  for ray_weight in (None, np.random.default_rng(5).uniform(0.5, 2.0, 3 * P * P)):
    inputs = _inputs(("coarse", "fine"), weight=ray_weight)
    loss = jax.jit(lambda i: term(i))
    a, b = loss(inputs), loss(inputs.replace(mask=jnp.ones(3 * P * P)))
    assert a[0].tobytes() == b[0].tobytes()
    assert a[1]["inliers"].tobytes() == b[1]["inliers"].tobytes()


def test_the_loss_with_masks_is_the_mean_over_kept_inliers():
  settings = robust.Settings(weight=0.7, inner_size=4)
  inputs = _inputs(("coarse", "fine"))
  kept = np.random.default_rng(4).uniform(size=3 * P * P) > 0.4
  target = np.where(kept[:, None], np.asarray(inputs.target), 0.0)  # masked: black target
  inputs = inputs.replace(target=jnp.asarray(target, jnp.float32),
                          weight=jnp.asarray(kept, jnp.float32),
                          mask=jnp.asarray(kept, jnp.float32))
  loss, stats = robust.Robust(0.7, P, settings)(inputs)
  want = 0.0
  for name in ("coarse", "fine"):
    residual = np.mean((np.asarray(inputs.outputs[name]["rgb"]) - target) ** 2, -1)
    mask, threshold = _mask_ref(residual.reshape(-1, P, P), settings, kept.reshape(-1, P, P))
    want += residual[mask.reshape(-1)].mean()
  np.testing.assert_allclose(loss, 0.7 * want, rtol=1e-5)
  np.testing.assert_allclose(stats["inliers"], mask.sum() / kept.sum(), rtol=1e-6)
  np.testing.assert_allclose(stats["threshold"], threshold, rtol=1e-5)


@pytest.mark.parametrize("masks", [False, True])
def test_the_warm_up_is_the_plain_loss_then_the_trimmed_one(masks):
  k = 5
  inputs = _inputs(("coarse", "fine"))
  if masks:
    kept = np.random.default_rng(4).uniform(size=3 * P * P) > 0.4
    inputs = inputs.replace(weight=jnp.asarray(kept, jnp.float32),
                            mask=jnp.asarray(kept, jnp.float32))
  settings = robust.Settings(weight=1.0, inner_size=4)
  warm = robust.Robust(1.0, P, robust.Settings(weight=1.0, inner_size=4, warmup_steps=k))
  trimmed = jax.jit(robust.Robust(1.0, P, settings))(inputs)[0]
  plain = colour.Colour()(inputs)[0]  # the colour term's loss (squared error, passes added)
  kept = np.ones(3 * P * P, bool) if not masks else kept
  want = sum(np.mean((np.asarray(inputs.outputs[name]["rgb"])[kept]
                      - np.asarray(inputs.target)[kept]) ** 2) for name in ("coarse", "fine"))
  np.testing.assert_allclose(plain, want, rtol=1e-5)
  loss = jax.jit(lambda step: warm(inputs.replace(step=step)))
  for step in range(0, 2 * k):
    value, stats = loss(jnp.int32(step))
    if step < k:
      np.testing.assert_allclose(value, plain, rtol=1e-5)
      np.testing.assert_allclose(stats["inliers"], 1.0, rtol=1e-6)  # nothing trimmed
    else:
      assert value.tobytes() == np.asarray(trimmed).tobytes()
  assert abs(float(plain) - float(trimmed)) > 0.01  # the two differ here
  with pytest.raises(ValueError, match="warmup_steps > 0 needs the step"):
    warm(inputs)


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
    robust.build(robust.Settings(weight=1.0), losses.Context(None, pose_refinement=False))


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


def test_the_train_step_warms_up_on_the_plain_loss():
  # Step 0 of warmup_steps=1 is the colour loss of a plain run on the same patches (the same
  # draw, the same parameters); step 1 trims (a 2 x 2 middle: a 4 x 4 patch is not kept whole).
  plain = _two_steps({"train.batching": "patches", "train.patch_size": 4})
  warm = _two_steps({"loss.robust.weight": 1.0, "train.patch_size": 4,
                     "loss.robust.inner_size": 2, "loss.robust.warmup_steps": 1})
  np.testing.assert_allclose(warm[0][0]["loss"], plain[0][0]["loss"], rtol=1e-5)
  np.testing.assert_allclose(warm[0][0]["robust/inliers"], 1.0, rtol=1e-6)
  assert warm[0][1]["robust/inliers"] < 0.95
  assert "colour/masked_share" not in warm[0][0]  # crowd has no masks


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


def test_patches_are_drawn_on_kept_pixels():
  # A mask that keeps a 5 x 6 box of image 1 and a 3 x 3 box of image 2 (image 0 all masked):
  # every patch holds a kept pixel, most of a batch's pixels are kept, and image 0 is never
  # drawn; the uniform draw (the same data without `kept`) mostly misses them.
  num, height, width, size = 3, 24, 32, 8
  mask = np.zeros((num, height, width), np.float32)
  mask[1, 2:7, 20:26] = 1.0  # near the top edge: the patch is moved inside the image
  mask[2, 14:17, 0:3] = 1.0  # at the left edge
  data = train_batches.TrainData(
      rays=None, rgb=jnp.zeros((num, height * width, 3)), acc=jnp.ones((num, height * width)),
      poses=jnp.tile(jnp.eye(4), (num, 1, 1)),
      camera=(height, width, (24.0, 24.0, 16.0, 12.0), 2.0, 6.0, 0.5, False),
      kept=jnp.asarray(np.flatnonzero(mask), jnp.int32),
      mask=jnp.asarray(mask.reshape(num, -1)))
  settings = train_batches.BatchSettings(batching="patches", batch_rays=8 * 64, patch_size=size)
  kept_share, uniform_share, images = [], [], set()
  for seed in range(10):
    for d, shares in ((data, kept_share), (data.replace(kept=None), uniform_share)):
      batch = train_batches.draw_batch(d, settings, jax.random.PRNGKey(seed))
      image = np.asarray(batch.image).reshape(-1, size, size)
      pixel = np.asarray(batch.pixel).reshape(-1, size, size)
      for k in range(image.shape[0]):  # whole patches of one image, inside it
        row, col = divmod(int(pixel[k, 0, 0]), width)
        assert np.all(image[k] == image[k, 0, 0]) and row + size <= height and col + size <= width
        np.testing.assert_array_equal(pixel[k], (row + np.arange(size))[:, None] * width
                                      + col + np.arange(size))
      held = mask.reshape(num, -1)[image, pixel]
      np.testing.assert_array_equal(np.asarray(batch.mask), held.reshape(-1))
      shares.append(held.mean())
      if d is data:
        assert held.reshape(-1, size * size).any(-1).all()  # every patch holds a kept pixel
        images.update(image[:, 0, 0].tolist())
  assert images == {1, 2}
  assert np.mean(kept_share) > 0.25 and np.mean(kept_share) > 5 * np.mean(uniform_share)
