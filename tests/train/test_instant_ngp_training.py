"""instant-ngp's training extras, each off by default: Huber's colour loss
(loss.colour.huber_delta), a coupled L2 on the networks' weight matrices (train.network_l2) and the
weights' moving average that scores and renders (train.ema_decay). Each is checked against a
brute-force reference written here."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import serialization

from nerf_jax.run import builders, experiment
from nerf_jax.train import optimizer
from nerf_jax.run.signature import init_state, model_signature, state_template
from nerf_jax.train import checkpoints, losses, train_step
from nerf_jax.train.losses import colour
from tests.helpers import params_equal
from tests.helpers import small_config


# --- Huber's colour loss -------------------------------------------------------------------

def _huber_brute(error, delta):
  out = np.empty_like(error)
  for i, e in enumerate(error.ravel()):
    out.ravel()[i] = e * e / 2 if abs(e) <= delta else delta * (abs(e) - delta / 2)
  return out


def test_huber_matches_its_definition_and_its_gradient_is_the_clipped_error():
  error = np.array([-0.7, -0.1, -0.03, 0.0, 0.02, 0.1, 0.2500001, 3.0], np.float32)
  np.testing.assert_allclose(colour.huber(jnp.asarray(error), 0.1), _huber_brute(error, 0.1),
                             rtol=1e-6, atol=1e-9)
  grad = jax.vmap(jax.grad(lambda e: colour.huber(e, 0.1)))(jnp.asarray(error))
  np.testing.assert_allclose(grad, np.clip(error, -0.1, 0.1), rtol=1e-6)
  # Continuous at the knee: both branches give delta²/2 there.
  below, above = colour.huber(jnp.float32(0.1), 0.1), colour.huber(jnp.float32(0.1 + 1e-6), 0.1)
  assert abs(float(above) - float(below)) < 2e-7


def _colour_inputs(complete=None):
  rng = np.random.default_rng(0)
  rgb = rng.uniform(size=(6, 3)).astype(np.float32)
  target = rng.uniform(size=(6, 3)).astype(np.float32)
  coarse = {"rgb": jnp.asarray(rgb)}
  if complete is not None:  # a sample budget's outputs (render/renderer.py): both, always
    coarse["complete"] = jnp.asarray(complete)
    coarse["valid_samples"] = jnp.full(6, 4, jnp.int32)
  inputs = losses.LossInputs({"coarse": coarse}, jnp.asarray(target), None, {})
  return inputs, rgb, target


@pytest.mark.parametrize("complete", [None, [True, False, True, True, False, True]])
def test_the_huber_colour_loss_is_the_mean_over_whole_rays_and_psnr_stays_the_squared_errors(
    complete):
  inputs, rgb, target = _colour_inputs(complete)
  loss, stats = colour.Colour(huber_delta=0.1)(inputs)
  keep = np.ones(6, bool) if complete is None else np.array(complete)
  error = (rgb - target)[keep]
  np.testing.assert_allclose(loss, _huber_brute(error, 0.1).mean(), rtol=1e-5)
  mse = np.mean(error ** 2)
  np.testing.assert_allclose(stats["psnr"], -10 * np.log10(mse), rtol=1e-5)
  # Off (0) it is the squared error, as before.
  plain, _ = colour.Colour()(inputs)
  np.testing.assert_allclose(plain, mse, rtol=1e-5)


def test_a_negative_huber_delta_is_refused_naming_the_field():
  config = small_config(**{"loss.colour.huber_delta": -0.1})
  with pytest.raises(ValueError, match="config.loss.colour.huber_delta=-0.1"):
    builders.loss_terms(config, builders.make_ray_renderer(config))


# --- L2 on the networks' weight matrices ---------------------------------------------------

def _tree():
  params = {"coarse": {"Dense_0": {"kernel": jnp.array([[0.5, -2.0]]), "bias": jnp.array([1.0])},
                       "hash_table": jnp.array([[3.0, -1.0]])},
            "poses": jnp.array([[4.0, -0.5]])}  # a camera's correction, as pose refinement
  grads = jax.tree_util.tree_map(lambda p: jnp.full_like(p, 0.25), params)
  return params, grads


def _adam_brute(params, grads, steps, lr, b1, b2, eps, l2_leaves, l2):
  """Adam of each leaf on its own, λ·w added to the gradient of the leaves in l2_leaves."""
  out = {}
  for name, w in params.items():
    w, g = np.array(w, np.float64), np.array(grads[name], np.float64)
    m = v = 0.0
    for t in range(1, steps + 1):
      gt = g + (l2 * w if name in l2_leaves else 0.0)
      m, v = b1 * m + (1 - b1) * gt, b2 * v + (1 - b2) * gt * gt
      w = w - lr * (m / (1 - b1 ** t)) / (np.sqrt(v / (1 - b2 ** t)) + eps)
    out[name] = w
  return out


def _flat(tree):
  return {jax.tree_util.keystr(path): leaf
          for path, leaf in jax.tree_util.tree_leaves_with_path(tree)}


@pytest.mark.parametrize("l2", [0.0, 0.5])
def test_network_l2_adds_lambda_w_to_the_gradient_of_weight_matrices_only(l2):
  config = small_config(**{"train.network_l2": l2, "train.warmup_steps": 0, "train.lr": 1e-2,
                           "train.lr_final": 1e-2, "train.adam_b2": 0.99,
                           "train.adam_eps": 1e-3})
  tx = optimizer.make_optimizer(builders.optimizer_settings(config))
  params, grads = _tree()
  state = tx.init(params)
  for _ in range(3):
    updates, state = tx.update(grads, state, params)
    params = jax.tree_util.tree_map(lambda p, u: p + u, params, updates)
  start, grads = _tree()
  kernel = "['coarse']['Dense_0']['kernel']"
  expected = _adam_brute(_flat(start), _flat(grads), 3, 1e-2, 0.9, 0.99, 1e-3, {kernel}, l2)
  for name, leaf in _flat(params).items():
    np.testing.assert_allclose(leaf, expected[name], rtol=1e-5, err_msg=name)
  if l2:  # λ·w = 0.25 against -1.0 turns the kernel's second entry's gradient round
    assert float(params["coarse"]["Dense_0"]["kernel"][0, 1]) > -2.0 + 0.02


def test_a_negative_network_l2_is_refused_naming_the_field():
  config = small_config(**{"train.network_l2": -1e-6})
  with pytest.raises(ValueError, match="config.train.network_l2=-1e-06"):
    builders.optimizer_settings(config)


# --- the weights' moving average -------------------------------------------------------------

def test_moving_average_is_the_decayed_sum_and_off_stays_off():
  ema = {"params": {"a": jnp.array([1.0, 2.0])}}
  out = train_step.moving_average(ema, {"a": jnp.array([3.0, -2.0])}, 0.75)
  np.testing.assert_allclose(out["params"]["a"], [0.75 * 1 + 0.25 * 3, 0.75 * 2 - 0.25 * 2])
  assert train_step.moving_average({}, {"a": jnp.ones(2)}, 0.75) == {}


EMA = {"train.ema_decay": 0.8, "train.max_steps": 4, "train.checkpoint_every": 4,
       "train.log_every": 4}


@pytest.fixture(scope="module")
def ema_run():
  """(config, Experiment, the params after each of 4 steps, the final state), stepped by hand
  so the reference can average what each step left."""
  config = small_config(EMA)
  exp = experiment.setup(config)
  step, data = builders.make_train_step(exp), builders.make_train_data(exp)
  state = init_state(exp)
  seen = [jax.device_get(state.params)]
  for _ in range(4):
    state, _ = step(state, data, jax.random.PRNGKey(0))
    seen.append(jax.device_get(state.params))
  return config, exp, seen, jax.device_get(state)


def test_the_train_state_keeps_the_average_of_every_steps_weights(ema_run):
  _, _, seen, state = ema_run
  expected = jax.tree_util.tree_map(np.asarray, seen[0])
  for params in seen[1:]:
    expected = jax.tree_util.tree_map(lambda a, p: 0.8 * a + 0.2 * p, expected, params)
  leaves = zip(jax.tree_util.tree_leaves(state.ema["params"]),
               jax.tree_util.tree_leaves(expected))
  for got, want in leaves:
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
  # Renders and scores take the average; the train step keeps training the last weights.
  assert state.variables["params"] is state.ema["params"]
  assert state.training_variables["params"] is state.params
  assert not params_equal(state.ema["params"], state.params)


def test_a_run_without_the_average_keeps_none_and_renders_its_weights():
  config = small_config(**{"train.max_steps": 1})
  exp = experiment.setup(config)
  state = init_state(exp)
  assert state.ema == {} and state.variables["params"] is state.params
  assert "ema" not in model_signature(config)


def test_the_average_is_checkpointed_and_an_older_checkpoint_is_refused_in_one_line(
    ema_run, tmp_path):
  config, exp, _, state = ema_run
  signature = model_signature(config)
  assert signature["ema"] is True
  workdir = str(tmp_path)
  checkpoints.save(workdir, 4, state, signature)
  restored = checkpoints.restore(checkpoints.latest_path(workdir),
                                 state_template(exp), signature)
  assert params_equal(restored.ema["params"], state.ema["params"])
  # A checkpoint of the same run without the average (saved before it was set) is refused
  # by the signature, with the field named, not restored into a state that expects one.
  plain = dict(signature)
  del plain["ema"]
  old = serialization.to_state_dict(state)
  del old["ema"]
  checkpoints.save(str(tmp_path / "old"), 4, old, plain)
  with pytest.raises(checkpoints.CheckpointError, match="ema: checkpoint None vs config True"):
    checkpoints.restore(checkpoints.latest_path(str(tmp_path / "old")),
                        state_template(exp), signature)


@pytest.mark.parametrize("decay", [-0.1, 1.0])
def test_an_ema_decay_outside_zero_to_one_is_refused_naming_the_field(decay):
  config = small_config(**{"train.ema_decay": decay})
  with pytest.raises(ValueError, match=f"config.train.ema_decay={decay}"):
    builders.step_settings(experiment.setup(config))
