"""The test session's set-up and fixtures: the environment every test runs in (a GPU's arithmetic
emulated, deterministic ops, the compilation cache), one trained workdir per test session, NaNs
that raise, a fresh small config. Helper functions live in tests/helpers.py, the one helpers
module.

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
import pytest

from nerf_jax.run import train_lib
from tests.helpers import small_config


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







@pytest.fixture
def config():
  """A fresh `small_config()` (configs/debug.py, no rendering after training) for each test."""
  return small_config()


@pytest.fixture
def cpu_decisions(monkeypatch):
  """auto's CPU decisions whatever backend the suite runs on: on a GPU auto takes configs/gpu/
  (its GPU branch is tested with backend='gpu' passed in, tests/run/test_auto.py)."""
  import jax  # pylint: disable=import-outside-toplevel
  monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
