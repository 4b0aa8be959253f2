"""Shared test scaffolding: the configs shipped, one trained workdir per test session, the scores
of trivial answers, restoring a run's parameters, comparing them, reading TensorBoard events.

Markers: `slow` (a test that trains or spawns processes for more than ~10 s). The README's test
command runs everything; `python -m pytest -m "not slow"` is the quick loop while editing.
"""

import os
import tempfile

# Before jax and nerf_jax are imported, so that every test, subprocesses included, runs with them: a
# GPU's arithmetic emulated on the CPU (nerf_jax/backend/precision.py: TF32 matmuls wherever a
# matmul does not ask for full float32, approximate float32 division), so that code which only holds
# with a CPU's exact arithmetic fails here as it would on a GPU; and XLA's deterministic ops
# (train.deterministic), so the bitwise-resume tests hold on a GPU too.
os.environ.setdefault("NERF_JAX_EMULATE", "tf32,div")
# XLA's persistent compilation cache, shared by the workers and their subprocesses: many tests
# build the same small step or render from fresh closures, whose programs are identical, and an
# identical program (same HLO, flags, jax and XLA versions: the cache key) is compiled once. It
# changes no number: a hit loads the executable that compiling would have produced. Compiling
# is a large share of this suite's time. JAX_COMPILATION_CACHE_DIR= (empty) turns it off.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.join(
    tempfile.gettempdir(), f"nerf_jax_test_xla_cache_{os.getuid()}"))  # one per user
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.1")
os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(2 << 30))  # bytes; oldest go first
from nerf_jax.backend import determinism  # noqa: E402  (imports jax; starts no backend)
determinism.require()

import jax  # noqa: E402  (after the environment above)
import numpy as np
import pytest

from nerf_jax.evaluate import metrics
from nerf_jax.render import background
from nerf_jax.run import experiment
from nerf_jax.run import train_lib
from nerf_jax.configs import debug
from tests.helpers import small_config

# The margin (dB) a trained model must keep above the better trivial answer on the same views.
# Measured: the shared run scores 24.6 dB where the mean training image scores 20.2 (+4.4 dB).
TRIVIAL_MARGIN_DB = 3.0


def shipped_configs():
  """Every config name shipped under configs/ ('fast', 'scenes/fog', ...): tests that should hold
  for all configs use this list, so a new config file is checked without editing them."""
  root = os.path.dirname(debug.__file__)  # the installed configs/ package
  names = []
  for sub in ("", "scenes/", "gpu/"):
    names += sorted(sub + f[:-3] for f in os.listdir(os.path.join(root, sub))
                    if f.endswith(".py") and f != "__init__.py")
  return names


# The shared trained run: debug.py's model on 24 views (20 train, 4 test) of 32×32 of the
# `diffuse` scene, 600 steps of 512 rays, evaluating at step 300 and at the end, rendering the
# test views and a 4-frame video after training.
SHARED_RUN = {"data.num_views": 24, "data.image_size": 32, "data.holdout_from": 20,
              "train.max_steps": 600, "train.batch_rays": 512, "train.log_every": 300,
              "train.eval_every": 300, "train.checkpoint_every": 600,
              "render.video_frames": 4, "render.after_training": True}


@pytest.fixture(scope="module")
def debug_nans():
  """jax_debug_nans on for a module that asks for it (`pytestmark`): a NaN anywhere raises."""
  previous = jax.config.jax_debug_nans
  jax.config.update("jax_debug_nans", True)
  yield
  jax.config.update("jax_debug_nans", previous)


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
  """The shared trained run, built once per test session (about 15-30 s on 2 cores); tests only
  read it. (workdir: pathlib.Path, result: the metrics train_and_evaluate returned)."""
  workdir = tmp_path_factory.mktemp("shared") / "run"
  result = train_lib.train_and_evaluate(small_config(SHARED_RUN), str(workdir))
  return workdir, result


def trivial_psnrs(exp):
  """PSNR (dB, mean over `exp`'s test views) of two answers that learn nothing: the background
  alone ('background': all black on black data) and the mean training image ('mean')."""
  bg = background.parse(exp.config.data.background)
  train = background.images_on_background(exp.train_ds, bg)[1]
  test = background.images_on_background(exp.test_ds, bg)[1]
  mean = train.mean(axis=0)
  score = lambda guess: float(np.mean([metrics.psnr(np.broadcast_to(guess, t.shape), t)
                                       for t in test]))
  return {"background": score(bg), "mean": score(mean)}


def assert_beats_trivial(psnr, exp, margin=TRIVIAL_MARGIN_DB):
  """`psnr` (dB on exp's test views) is `margin` dB above the better trivial answer."""
  trivial = trivial_psnrs(exp)
  assert psnr > max(trivial.values()) + margin, (psnr, trivial)


def restored_variables(workdir):
  """The variables of the newest checkpoint in `workdir`: {'params': ..., **buffers} (the
  trained parameters and the occupancy grid, if any)."""
  return experiment.restore(str(workdir))[1].variables


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
  """A fresh `small_config()` (configs/debug.py, no rendering after training) for each test."""
  return small_config()
