"""Tests of nerf_jax.train.train_step.make_train_step on a tiny grid renderer: a step takes a
gradient step of losses.total on the batch it draws (checked against that loss and its gradient
computed here from the same draws), and a non-finite step is reported, not applied."""

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from nerf_jax.run import builders, experiment
from nerf_jax.train import losses, train_batches, train_step
from nerf_jax.train.state import TrainState
from tests.helpers import TINY_GRID, small_config

LR = 0.1  # plain SGD: a step moves the parameters by exactly -LR times the gradient


@pytest.fixture(scope="module")
def run():
  """(ray_renderer, terms, settings, train data, a fresh state's params) of a tiny grid config on
  a fixed background (no random background: the targets are the batch's colours), with fewer
  rays and samples and no rematerialised chunks: a smaller program to compile."""
  config = small_config(TINY_GRID, base="fast", **{
      "train.random_background": False, "train.batch_rays": 64, "num_samples": 8,
      "train.remat_chunk": 0})
  exp = experiment.setup(config)
  ray_renderer = builders.training_renderer(exp)
  terms = builders.loss_terms(config, ray_renderer)
  settings = builders.step_settings(exp)
  params = ray_renderer.init(jax.random.PRNGKey(0))["params"]
  return ray_renderer, terms, settings, builders.make_train_data(exp), params


def _state(params, tx):
  """A fresh TrainState of (host copies of) `params`: the step donates its state."""
  params = jax.tree_util.tree_map(jnp.array, params)
  return TrainState(step=jnp.int32(0), params=params, opt_state=tx.init(params),
                    bad_step=jnp.int32(-1), buffers={}, ema={})


def _host(tree):
  return jax.tree_util.tree_map(lambda a: np.array(a, copy=True), tree)


def _reference_loss(ray_renderer, terms, settings, data, run_key, step):
  """params -> (loss, stats) of step `step` as the step promises it: the batch drawn from
  fold_in(run_key, step), rendered with the second half of that key's split (whose own first
  half renders), on the fixed background, added up by losses.total."""
  key = jax.random.fold_in(run_key, step)
  batch_key, render_key = jax.random.split(key)
  batch = train_batches.draw_batch(data, settings.batch, batch_key, jnp.int32(step), run_key)
  render_key, _ = jax.random.split(render_key)

  def loss(params):
    outs = ray_renderer.render({"params": params}, batch.rays, render_key,
                               jnp.asarray(settings.background), settings.remat_chunk)
    return losses.total(terms, losses.LossInputs(outs, batch.rgb, batch.rays, params))
  return loss


def test_a_step_is_a_gradient_step_of_the_loss_terms_total(run):
  ray_renderer, terms, settings, data, params = run
  tx = optax.sgd(LR)
  step = train_step.make_train_step(ray_renderer, tx, terms, settings)
  run_key = jax.random.PRNGKey(7)
  before = _host(params)
  state, stats = step(_state(params, tx), data, run_key)
  loss_fn = _reference_loss(ray_renderer, terms, settings, data, run_key, 0)
  (want_loss, want_stats), grads = jax.jit(jax.value_and_grad(loss_fn, has_aux=True))(params)
  assert set(stats) == set(want_stats) == {"loss", "colour/psnr"}
  np.testing.assert_allclose(stats["loss"], want_loss, rtol=1e-6)
  np.testing.assert_allclose(stats["colour/psnr"], want_stats["colour/psnr"], rtol=1e-6)
  assert int(state.step) == 1 and int(state.bad_step) == -1
  moved = jax.tree_util.tree_map(lambda p, g: p - LR * np.asarray(g), before, grads)
  for got, want, old in zip(jax.tree_util.tree_leaves(state.params),
                            jax.tree_util.tree_leaves(moved), jax.tree_util.tree_leaves(before)):
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
  assert any(not np.array_equal(got, old) for got, old in zip(
      jax.tree_util.tree_leaves(state.params), jax.tree_util.tree_leaves(before)))


@dataclasses.dataclass(frozen=True)
class NotANumber:
  """A term whose loss is NaN wherever the render is: its gradient is NaN too."""
  name: ClassVar[str] = "not_a_number"

  def __call__(self, inputs):
    return jnp.float32(jnp.nan) * jnp.mean(inputs.outputs["coarse"]["rgb"]), {}


def test_a_non_finite_step_is_reported_and_not_applied(run):
  ray_renderer, terms, settings, data, params = run
  tx = optax.adam(1e-2)
  run_key = jax.random.PRNGKey(7)
  bad = train_step.make_train_step(ray_renderer, tx, [*terms, NotANumber()], settings)
  before = _host(params)
  state = _state(params, tx)
  opt_before = _host(state.opt_state)
  state, stats = bad(state, data, run_key)
  assert not np.isfinite(float(stats["loss"]))
  assert int(state.step) == 1 and int(state.bad_step) == 0  # the step it happened at
  for got, want in zip(jax.tree_util.tree_leaves(state.params), jax.tree_util.tree_leaves(before)):
    np.testing.assert_array_equal(got, want)  # the last good parameters, bit for bit
  for got, want in zip(jax.tree_util.tree_leaves(state.opt_state),
                       jax.tree_util.tree_leaves(opt_before)):
    np.testing.assert_array_equal(got, want)  # and Adam's moments and count
  # A good step after it trains again and keeps the first bad step's number.
  good = train_step.make_train_step(ray_renderer, tx, terms, settings)
  state, stats = good(state, data, run_key)
  assert np.isfinite(float(stats["loss"])) and int(state.step) == 2
  assert int(state.bad_step) == 0
  assert any(not np.array_equal(got, old) for got, old in zip(
      jax.tree_util.tree_leaves(state.params), jax.tree_util.tree_leaves(before)))
