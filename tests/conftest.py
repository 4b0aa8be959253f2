"""Shared test scaffolding: the shrunk config, one trained workdir per test session, the scores
of trivial answers, restoring a run's parameters, comparing them, reading TensorBoard events.

Markers: `slow` (a test that trains or spawns processes for more than ~10 s). The README's test
command runs everything; `python -m pytest -m "not slow"` is the quick loop while editing.
"""

import os

import jax
import numpy as np
import pytest

from nerf_jax import background, experiment, metrics, outputs, train_lib
from nerf_jax.configs import debug

# The margin (dB) a trained model must keep above the better trivial answer on the same views.
# Measured: the shared run scores 24.6 dB where the mean training image scores 20.2 (+4.4 dB).
TRIVIAL_MARGIN_DB = 3.0


def shipped_configs():
  """Every config name shipped under configs/ ('fast', 'scenes/fog', ...): tests that should hold
  for all configs use this list, so a new config file is checked without editing them."""
  root = os.path.dirname(debug.__file__)  # the installed configs/ package
  names = []
  for sub in ("", "scenes/"):
    names += sorted(sub + f[:-3] for f in os.listdir(os.path.join(root, sub))
                    if f.endswith(".py") and f != "__init__.py")
  return names


def tiny_config(**train):
  """configs/debug.py (24×24 views, a small MLP, 20 steps) with no rendering after training;
  `train` overrides config.train fields."""
  config = debug.get_config()
  config.render.after_training = False
  for k, v in train.items():
    config.train[k] = v
  return config


def shared_config():
  """The config of the shared trained run: debug.py's model on 24 views (20 train, 4 test) of
  32×32 of the `diffuse` scene, 600 steps of 512 rays, evaluating at step 300 and at the end,
  rendering the test views and a 4-frame video after training."""
  config = debug.get_config()
  config.data.num_views, config.data.image_size, config.data.holdout_from = 24, 32, 20
  config.train.max_steps = 600
  config.train.batch_rays = 512
  config.train.log_every = config.train.eval_every = 300
  config.train.checkpoint_every = 600
  config.render.video_frames = 4
  return config


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
  """The shared trained run, built once per test session (about 15-30 s on 2 cores); tests only
  read it. (workdir: pathlib.Path, result: the metrics train_and_evaluate returned)."""
  workdir = tmp_path_factory.mktemp("shared") / "run"
  result = train_lib.train_and_evaluate(shared_config(), str(workdir))
  return workdir, result


def trivial_psnrs(exp):
  """PSNR (dB, mean over `exp`'s test views) of two answers that learn nothing: the background
  alone ('background': all black on black data) and the mean training image ('mean')."""
  train = outputs.images_on_background(exp.train_ds, exp.config)[1]
  test = outputs.images_on_background(exp.test_ds, exp.config)[1]
  bg = background.parse(exp.config.data.background)
  mean = train.mean(axis=0)
  score = lambda guess: float(np.mean([metrics.psnr(np.broadcast_to(guess, t.shape), t)
                                       for t in test]))
  return {"background": score(bg), "mean": score(mean)}


def assert_beats_trivial(psnr, exp, margin=TRIVIAL_MARGIN_DB):
  """`psnr` (dB on exp's test views) is `margin` dB above the better trivial answer."""
  trivial = trivial_psnrs(exp)
  assert psnr > max(trivial.values()) + margin, (psnr, trivial)


def restored_params(workdir):
  """The parameters of the newest checkpoint in `workdir`."""
  return experiment.restore(str(workdir))[1].params


def params_equal(a, b):
  """Whether two parameter trees hold exactly the same arrays."""
  leaves = zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
  return all(np.array_equal(x, y) for x, y in leaves)


def tensorboard_scalars(workdir):
  """{tag: [(step, value), ...]} of the scalar TensorBoard events in workdir/tb (a TFRecord
  reader: each record is its length, the length's crc, the Event proto, the proto's crc)."""
  from tensorboardX.proto import event_pb2  # pylint: disable=import-outside-toplevel
  tags = {}
  folder = os.path.join(str(workdir), "tb")
  for name in sorted(os.listdir(folder)):
    data = open(os.path.join(folder, name), "rb").read()
    pos = 0
    while pos < len(data):
      length = int.from_bytes(data[pos:pos + 8], "little")
      event = event_pb2.Event.FromString(data[pos + 12:pos + 12 + length])
      pos += 12 + length + 4
      for value in event.summary.value:
        if value.WhichOneof("value") == "simple_value":
          tags.setdefault(value.tag, []).append((event.step, value.simple_value))
  return tags


@pytest.fixture
def config():
  """A fresh `tiny_config()` for each test."""
  return tiny_config()
