"""A masked pixel (Dataset.masks) is never trained on: with the masked pixels set to random
colours, a few train steps give bit-identical losses, statistics and parameters whatever the
colours, for random-ray and whole-image batches and RobustNeRF's patches; random rays are drawn
from kept pixels alone, whole images and patches weight masked pixels by exactly 0, and each step
logs the share of its rays that are masked (colour/masked_share)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data.dataset import Dataset
from nerf_jax.run import builders, experiment
from nerf_jax.train import train_batches, train_step
from nerf_jax.train.state import TrainState
from tests.helpers import TINY_GRID, small_config

STEPS = 3


@pytest.fixture(scope="module")
def exp():
  """A tiny grid experiment (16 px views) whose training views carry random masks."""
  config = small_config(TINY_GRID, base="fast", **{"train.batch_rays": 64, "num_samples": 8,
                                                   "train.remat_chunk": 0})
  exp = experiment.setup(config)
  rng = np.random.default_rng(0)
  masks = (rng.random(exp.train_ds.images.shape[:3]) > 0.4).astype(np.float32)
  return dataclasses.replace(exp, train_ds=dataclasses.replace(exp.train_ds, masks=masks))


def _painted(exp, seed):
  """exp with its training images' masked pixels set to random colours drawn from `seed`."""
  ds = exp.train_ds
  noise = np.random.default_rng(seed).random(ds.images.shape).astype(np.float32)
  images = np.where(ds.masks[..., None] > 0, ds.images, noise)
  accs = None if ds.accs is None else np.where(ds.masks > 0, ds.accs, noise[..., 0])
  return dataclasses.replace(exp, train_ds=dataclasses.replace(ds, images=images, accs=accs))


def _trainer(exp, batching):
  """fn(exp) -> (stats of each step, final params) of STEPS Adam steps on exp's training data
  with `batching` ('rays' | 'images' | 'robust': RobustNeRF's trimmed loss on 4 x 4 patches):
  one step, compiled once for every exp of one shape."""
  config = exp.config.copy_and_resolve_references()
  if batching == "robust":
    config.loss.robust.weight, config.train.patch_size = 1.0, 4
  else:
    config.train.batching = batching
  exp = dataclasses.replace(exp, config=config)
  ray_renderer = builders.training_renderer(exp)
  tx = optax.adam(1e-2)
  step = train_step.make_train_step(ray_renderer, tx, builders.loss_terms(config, ray_renderer),
                                    builders.step_settings(exp))
  params = ray_renderer.init(jax.random.PRNGKey(0))["params"]

  def train(painted):
    fresh = jax.tree_util.tree_map(jnp.array, params)  # the step donates its state
    state = TrainState(step=jnp.int32(0), params=fresh, opt_state=tx.init(fresh),
                       bad_step=jnp.int32(-1), buffers={}, ema={})
    data = builders.make_train_data(dataclasses.replace(painted, config=config))
    history = []
    for _ in range(STEPS):
      state, stats = step(state, data, jax.random.PRNGKey(3))
      history.append({k: np.asarray(v) for k, v in stats.items()})
    return history, jax.tree_util.tree_map(np.asarray, state.params)
  return train


@pytest.mark.parametrize("batching", ["rays", "images", "robust"])
def test_masked_colours_never_reach_the_loss(exp, batching):
  train = _trainer(exp, batching)
  a, b = train(_painted(exp, 1)), train(_painted(exp, 2))
  shares = [stats["colour/masked_share"] for stats in a[0]]
  if batching == "rays":  # drawn from the kept pixels alone
    assert all(share == 0 for share in shares)
  else:  # about the masks' 40% (patches: fewer, each centred on a kept pixel)
    assert all(0 < share < 0.6 for share in shares)
  for stats_a, stats_b in zip(a[0], b[0]):
    assert set(stats_a) == set(stats_b)
    for name in stats_a:
      np.testing.assert_array_equal(stats_a[name], stats_b[name])
  for leaf_a, leaf_b in zip(jax.tree_util.tree_leaves(a[1]), jax.tree_util.tree_leaves(b[1])):
    np.testing.assert_array_equal(leaf_a, leaf_b)
  # The test has teeth: without the masks the two colourings train differently.
  bare = lambda e: dataclasses.replace(e, train_ds=dataclasses.replace(e.train_ds, masks=None))
  c, d = train(bare(_painted(exp, 1))), train(bare(_painted(exp, 2)))
  assert c[0][-1]["loss"] != d[0][-1]["loss"]


def test_random_rays_are_drawn_from_kept_pixels_and_images_weight_masked_by_zero(exp):
  data = builders.make_train_data(exp)
  mask = exp.train_ds.masks.reshape(len(exp.train_ds), -1)
  rays = train_batches.BatchSettings(batching="rays", batch_rays=4096)
  batch = train_batches.draw_batch(data, rays, jax.random.PRNGKey(5))
  assert mask[np.asarray(batch.image), np.asarray(batch.pixel)].all()
  assert batch.weight is None  # every drawn ray is kept: no weight needed
  images = train_batches.BatchSettings(batching="images", images_per_step=2)
  batch = train_batches.draw_batch(data, images, jax.random.PRNGKey(5))
  want = mask[np.asarray(batch.image), np.asarray(batch.pixel)]
  np.testing.assert_array_equal(batch.weight, want)
  assert not np.asarray(batch.rgb)[want == 0].any()  # masked colours are zeroed on the device


def test_per_image_cameras_draw_kept_pixels_alone():
  """Images of mixed sizes (one flat run of pixels) draw only kept pixels too."""
  rng = np.random.default_rng(1)
  sizes = (16, 8, 12)
  cameras = Cameras.stack([(n, n, (n * 1.0, n * 1.0, n / 2, n / 2)) for n in sizes])
  masks = [(rng.random((n, n)) > 0.5).astype(np.float32) for n in sizes]
  for m in masks:
    m[0, 0] = 1.0
  ds = Dataset([rng.random((n, n, 3)).astype(np.float32) for n in sizes],
               np.tile(np.eye(4, dtype=np.float32), (3, 1, 1)), (16.0, 16.0, 8.0, 8.0),
               image_cameras=cameras, masks=masks)
  data = train_batches.make_train_data(ds, (None, None, None, 2.0, 6.0, 0.5, False),
                                       np.zeros(3, np.float32))
  batch = train_batches.draw_batch(data, train_batches.BatchSettings(batch_rays=2048),
                                   jax.random.PRNGKey(0))
  kept = [masks[i].reshape(-1)[p] for i, p in zip(np.asarray(batch.image),
                                                   np.asarray(batch.pixel))]
  assert all(k == 1.0 for k in kept)
