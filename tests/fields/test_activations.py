"""Density activations and the learning-rate schedule: values against closed forms."""

import jax
import numpy as np
import pytest

from nerf_jax.fields import activations
from nerf_jax.train import optimizer
from tests.helpers import small_config

RAW = np.array([-30.0, -3.0, -1.0, 0.0, 0.5, 1.0, 4.0, 30.0, 87.0, 88.0, 89.0, 200.0])


def test_relu_values():
  np.testing.assert_array_equal(activations.relu(RAW), np.maximum(RAW, 0.0).astype(np.float32))


def test_softplus_is_shifted_by_minus_one():
  expected = np.log1p(np.exp(RAW.astype(np.float64) - 1.0))
  np.testing.assert_allclose(activations.shifted_softplus(RAW), expected, rtol=1e-6)
  assert float(activations.shifted_softplus(1.0)) == pytest.approx(np.log(2.0), rel=1e-6)


def test_exp_is_clamped_at_88_with_zero_gradient_above():
  expected = np.exp(np.minimum(RAW.astype(np.float64), 88.0))
  np.testing.assert_allclose(activations.safe_exp(RAW), expected, rtol=1e-6)
  grad = jax.vmap(jax.grad(lambda x: activations.safe_exp(x)))(RAW.astype(np.float32))
  np.testing.assert_allclose(grad[RAW < 88], expected[RAW < 88], rtol=1e-6)
  np.testing.assert_array_equal(grad[RAW > 88], 0.0)
  assert np.all(np.isfinite(activations.safe_exp(RAW)))


def test_schedule_warms_up_linearly_then_decays_to_lr_final():
  tc = small_config({"train.lr": 5e-3, "train.lr_final": 1e-4, "train.warmup_steps": 50,
                     "train.max_steps": 1050}, base="default").train
  schedule = optimizer.make_schedule(tc)
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
  schedule = optimizer.make_schedule(small_config(
      {"train.lr": 1e-2, "train.lr_final": 1e-3, "train.warmup_steps": 0,
       "train.max_steps": 100}, base="default").train)
  assert float(schedule(0)) == pytest.approx(1e-2, rel=1e-6)
  assert float(schedule(100)) == pytest.approx(1e-3, rel=1e-5)
