"""bench/child.py: a child's environment (this checkout first on its path, GPU preallocation
off where asked), a run logged to a file (its command line, exit status, a timeout), what a
child prints, and the JSON line a child prints (or a one-line error naming it)."""

import os
import sys

import pytest

from nerf_jax.bench import child


def test_a_child_imports_this_checkout_first_and_may_leave_the_gpu_unallocated(monkeypatch):
  monkeypatch.setenv("PYTHONPATH", "/elsewhere")
  monkeypatch.delenv("XLA_PYTHON_CLIENT_PREALLOCATE", raising=False)
  environment = child.env(preallocate=False)
  assert environment["PYTHONPATH"].split(os.pathsep) == [child.ROOT, "/elsewhere"]
  assert environment["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"
  assert "XLA_PYTHON_CLIENT_PREALLOCATE" not in child.env()  # preallocation: JAX's own default
  assert child.env(own_code=False)["PYTHONPATH"] == "/elsewhere"
  imported = child.python_line("import nerf_jax, os; print(os.path.dirname(os.path.dirname("
                               "nerf_jax.__file__)))", child.env())
  assert imported == child.ROOT


def test_a_logged_run_writes_its_command_and_output_and_returns_its_status(tmp_path):
  log = tmp_path / "log.txt"
  args = [sys.executable, "-c", "import sys; print('out'); print('err', file=sys.stderr); "
          "sys.exit(3)"]
  code, seconds = child.run_logged(args, str(log), command_line=True)
  assert code == 3 and seconds > 0
  lines = log.read_text().splitlines()
  assert lines[0] == "$ " + " ".join(args)
  assert sorted(lines[1:]) == ["err", "out"]  # stdout and stderr together


def test_a_logged_run_past_its_timeout_says_timeout(tmp_path):
  code, seconds = child.run_logged([sys.executable, "-c", "import time; time.sleep(30)"],
                                   str(tmp_path / "log.txt"), timeout=1)
  assert code == "timeout" and seconds < 20


def test_python_line_names_the_error_where_the_child_prints_nothing():
  assert child.python_line("print(' 6 ')") == "6"
  said = child.python_line("raise ValueError('no such thing')")
  assert said.startswith("unknown (") and "ValueError: no such thing" in said


def test_json_line_reads_the_last_line_or_names_the_failing_child():
  printed = "print('compiling'); import json; print(json.dumps({'size': 40, 'finite': True}))"
  assert child.json_line([sys.executable, "-c", printed]) == {"size": 40, "finite": True}
  with pytest.raises(RuntimeError, match=r"exited with status 1: KeyError: 'rss'$"):
    child.json_line([sys.executable, "-c", "{}['rss']"])
