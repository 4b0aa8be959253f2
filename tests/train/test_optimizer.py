"""The optimiser's parameter groups and Adam's settings (optimizer.make_optimizer)."""

import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.run import builders, config_lib
from nerf_jax.train import optimizer
from tests.helpers import small_config


def _train_config(**fields):
  config = config_lib.default()
  config.train.warmup_steps = 0  # the first step at the full rate
  config.train.lr = 1e-2
  for name, value in fields.items():
    config.train[name] = value
  return builders.optimizer_settings(config)


def _params():
  return {"coarse": {"Dense_0": {"kernel": jnp.ones((3, 4)), "bias": jnp.zeros(4)},
                     "grid_32": jnp.ones((2, 2, 2, 4))}}


def _first_update(train_config):
  tx = optimizer.make_optimizer(train_config)
  params = _params()
  grads = {"coarse": {"Dense_0": {"kernel": jnp.full((3, 4), 0.3), "bias": jnp.full(4, -2.0)},
                      "grid_32": jnp.full((2, 2, 2, 4), 5.0)}}
  updates, state = tx.update(grads, tx.init(params), params)
  return updates, state


@pytest.mark.parametrize("network_lr", [1e-4, 3e-2])
def test_network_lr_moves_the_mlp_at_its_own_rate_and_the_tables_at_lr(network_lr):
  # Adam's first step moves every parameter by its rate times the gradient's sign (m/√v = ±1).
  updates, _ = _first_update(_train_config(network_lr=network_lr))
  np.testing.assert_allclose(updates["coarse"]["Dense_0"]["kernel"], -network_lr, rtol=1e-4)
  np.testing.assert_allclose(updates["coarse"]["Dense_0"]["bias"], network_lr, rtol=1e-4)
  np.testing.assert_allclose(updates["coarse"]["grid_32"], -1e-2, rtol=1e-4)


def test_network_lr_off_is_one_adam_for_everything():
  updates, _ = _first_update(_train_config(network_lr=0.0))
  for leaf in (updates["coarse"]["Dense_0"]["kernel"], updates["coarse"]["grid_32"]):
    np.testing.assert_allclose(jnp.abs(leaf), 1e-2, rtol=1e-4)


@pytest.mark.parametrize("b2", [0.999, 0.99])
def test_adam_b2_sets_the_second_moment_decay(b2):
  _, state = _first_update(_train_config(adam_b2=b2))
  nu = [s for s in state if hasattr(s, "nu")][0].nu  # ν = (1 - b2) g² after one step
  np.testing.assert_allclose(nu["coarse"]["grid_32"], (1 - b2) * 25.0, rtol=1e-5)


@pytest.mark.parametrize("eps", [1e-8, 1e-15])
def test_adam_eps_floors_the_denominator(eps):
  # First step: update = -lr·g/(|g| + eps). A gradient of 1e-10 (a table row hit by few rays)
  # moves at ~lr/100 with optax's default 1e-8 and at ~lr with instant-ngp's 1e-15.
  tx = optimizer.make_optimizer(_train_config(adam_eps=eps))
  params = {"grid_32": jnp.ones(4)}
  updates, _ = tx.update({"grid_32": jnp.full(4, 1e-10)}, tx.init(params), params)
  np.testing.assert_allclose(updates["grid_32"], -1e-2 * 1e-10 / (1e-10 + eps), rtol=1e-4)


def test_schedule_warms_up_linearly_then_decays_to_lr_final():
  config = small_config({"train.lr": 5e-3, "train.lr_final": 1e-4, "train.warmup_steps": 50,
                         "train.max_steps": 1050}, base="default")
  schedule = optimizer.make_schedule(builders.optimizer_settings(config))
  lr = lambda step: float(schedule(step))
  assert lr(0) == 0.0
  assert lr(25) == pytest.approx(0.5 * 5e-3, rel=1e-6)
  assert lr(50) == pytest.approx(5e-3, rel=1e-6)
  # Exponential decay over the remaining 1000 steps: halfway is the geometric mean.
  assert lr(550) == pytest.approx(np.sqrt(5e-3 * 1e-4), rel=1e-5)
  assert lr(1050) == pytest.approx(1e-4, rel=1e-5)
  steps = np.arange(50, 1051)
  values = np.array([lr(s) for s in steps[::50]])
  np.testing.assert_allclose(values, 5e-3 * (1e-4 / 5e-3) ** ((steps[::50] - 50) / 1000),
                             rtol=1e-5)


def test_schedule_without_warm_up_starts_at_lr():
  schedule = optimizer.make_schedule(builders.optimizer_settings(small_config(
      {"train.lr": 1e-2, "train.lr_final": 1e-3, "train.warmup_steps": 0,
       "train.max_steps": 100}, base="default")))
  assert float(schedule(0)) == pytest.approx(1e-2, rel=1e-6)
  assert float(schedule(100)) == pytest.approx(1e-3, rel=1e-5)
