"""Repeatable runs on every backend (`train.deterministic`).

On a CPU a run repeats bit for bit from its seed, and a killed run resumes onto the same numbers.
On a GPU, XLA's scatter-add (the gradient of the grid and hash tables' gathers) adds with
atomics in whatever order the threads arrive, so two runs differ in the last bits and drift
apart. XLA's deterministic-ops flag makes every op repeatable (scatters sorted first); its cost
is in docs/usage.md. XLA reads XLA_FLAGS once, when jax starts its backends, so `require` must
run before the first computation.
"""

import os

FLAG = "--xla_gpu_deterministic_ops=true"


def enabled():
  """Whether XLA_FLAGS asks for deterministic ops in this process (and its subprocesses)."""
  return FLAG in os.environ.get("XLA_FLAGS", "").split()


def require():
  """Make this process's GPU computations repeatable: add FLAG to XLA_FLAGS before jax starts.

  Raises ValueError (one line) when jax has already started a GPU backend without it; a CPU
  backend is deterministic without the flag.
  """
  if enabled():
    return
  from jax._src import xla_bridge  # pylint: disable=import-outside-toplevel
  if xla_bridge.backends_are_initialized():
    import jax  # pylint: disable=import-outside-toplevel
    if jax.default_backend() == "cpu":
      return
    raise ValueError(f"train.deterministic needs XLA_FLAGS={FLAG} before jax starts its "
                       "backends; set it in the environment of this process")
  os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {FLAG}".strip()
