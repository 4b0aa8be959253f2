"""The benchmark's child processes: their environment (this checkout first on the path, so a
child imports the parent's code), a run with its output into a log, and a run that prints a
JSON line.

Nothing here starts a JAX backend: a parent that runs its stages in children holds no device
memory while they run.
"""

import json
import os
import subprocess
import sys
import time

# The directory holding the nerf_jax package: a child imports the same code as its parent.
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
NO_PREALLOCATION = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false"}  # children that share one GPU


def env(preallocate=True, own_code=True):
  """A child's environment: this process's, with ROOT first on PYTHONPATH where `own_code`, and
  without JAX's preallocation of GPU memory unless `preallocate`."""
  path = os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH")) if p)
  return {**os.environ, **({} if preallocate else NO_PREALLOCATION),
          **({"PYTHONPATH": path} if own_code else {})}


def run_logged(args, log, timeout=None, environment=None, command_line=False, **popen):
  """(exit status, or 'timeout' past `timeout` seconds (at least 1; None: no limit); wall
  seconds) of the child `args`, its
  stdout and stderr together into the file `log` (a path), after the line '$ args' with
  `command_line`. environment: the child's (`env`; None: this process's); popen: further
  arguments of subprocess.run (preexec_fn)."""
  start = time.perf_counter()
  with open(log, "w") as f:
    if command_line:
      f.write("$ " + " ".join(args) + "\n")
      f.flush()  # before the child's output
    try:
      code = subprocess.run(args, stdout=f, stderr=subprocess.STDOUT, env=environment,
                            timeout=None if timeout is None else max(timeout, 1), check=False,
                            **popen).returncode
    except subprocess.TimeoutExpired:
      code = "timeout"
  return code, time.perf_counter() - start


def python_line(code, environment=None):
  """What `python -c code` prints in a child (stripped), else 'unknown ([its last error
  line])'."""
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=environment, check=False)
  return out.stdout.strip() or f"unknown ({out.stderr.strip().splitlines()[-1:]})"


def json_line(args, environment=None):
  """The JSON object the child `args` prints on its last stdout line; a one-line RuntimeError
  naming the child and its last error line where it fails."""
  out = subprocess.run(args, capture_output=True, text=True, env=environment, check=False)
  if out.returncode != 0:
    last = (out.stderr.strip().splitlines() or ["no error output"])[-1]
    raise RuntimeError(f"{' '.join(args)} exited with status {out.returncode}: {last}")
  return json.loads(out.stdout.strip().splitlines()[-1])
