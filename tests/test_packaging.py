"""`pip install .` into a fresh virtual environment gives working console scripts and configs.

The environment sees this interpreter's site-packages for the dependencies (no network), but
nerf_jax itself and the configs come from the wheel built from this checkout.
"""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _run(args, cwd, timeout=600):
  env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # only what is installed
  return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def test_pip_install_gives_console_scripts_that_train_and_render(tmp_path):
  venv = tmp_path / "venv"
  res = _run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], tmp_path)
  assert res.returncode == 0, res.stderr[-2000:]
  bin_dir = venv / "bin"
  res = _run([str(bin_dir / "python"), "-m", "pip", "install", "-q", "--no-deps",
              "--no-build-isolation", ROOT], tmp_path)
  assert res.returncode == 0, res.stderr[-2000:]
  outside = tmp_path / "elsewhere"  # no configs/ folder here: the installed copy must be found
  outside.mkdir()
  res = _run([str(bin_dir / "python"), "-c", "import nerf_jax, configs; "
              "print(nerf_jax.__file__); print(configs.__file__)"], outside)
  assert res.returncode == 0, res.stderr[-2000:]
  assert all(line.startswith(str(venv)) for line in res.stdout.split()), res.stdout
  workdir = str(outside / "run")
  res = _run([str(bin_dir / "nerf-train"), "--config=configs/debug.py", f"--workdir={workdir}",
              "--config.train.max_steps=2", "--config.render.after_training=False"], outside)
  assert res.returncode == 0, res.stderr[-2000:]
  assert "test PSNR" in res.stdout
  res = _run([str(bin_dir / "nerf-render"), f"--workdir={workdir}", "--mode=eval"], outside)
  assert res.returncode == 0, res.stderr[-2000:]
  assert os.path.exists(os.path.join(workdir, "eval", "view_000.png"))
