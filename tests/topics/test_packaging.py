"""`pip install .` gives working console scripts and configs, and installs nothing but nerf_jax.

The package is installed with `pip install --target` into a fresh folder that this interpreter
puts first on its path: the dependencies come from the environment running the tests (a venv or
the system's), nerf_jax itself and its configs from the wheel built from this checkout. (A
nested `venv --system-site-packages` would see the base interpreter's packages, not an outer
venv's, and fail inside one.)
"""

import os
import shutil
import subprocess
import sys

import pytest

from tests.helpers import ROOT


def _run(args, cwd, target, timeout=600):
  env = dict(os.environ, PYTHONPATH=str(target))  # the installed copy, not this checkout
  return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_pip_install_gives_console_scripts_that_train_and_render(tmp_path):
  target = tmp_path / "site"
  res = _run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
              "--target", str(target), ROOT], tmp_path, target)
  assert res.returncode == 0, res.stderr[-2000:]
  top = {name for name in os.listdir(target) if not name.endswith((".dist-info", ".egg-info"))}
  assert top == {"nerf_jax", "bin"}, top  # no top-level `configs` to shadow or be shadowed
  outside = tmp_path / "elsewhere"  # no configs/ folder here: the installed copy must be found
  outside.mkdir()
  res = _run([sys.executable, "-c", "import nerf_jax, nerf_jax.configs.fast as f; "
              "print(nerf_jax.__file__); print(f.__file__)"], outside, target)
  assert res.returncode == 0, res.stderr[-2000:]
  assert all(line.startswith(str(target)) for line in res.stdout.split()), res.stdout
  workdir = str(outside / "run")
  res = _run([str(target / "bin" / "nerf-train"), "--config=debug", f"--workdir={workdir}",
              "--config.train.max_steps=2", "--config.render.after_training=False"], outside,
             target)
  assert res.returncode == 0, res.stderr[-2000:]
  assert "test PSNR" in res.stdout
  res = _run([str(target / "bin" / "nerf-render"), f"--workdir={workdir}", "--mode=eval"],
             outside, target)
  assert res.returncode == 0, res.stderr[-2000:]
  assert os.path.exists(os.path.join(workdir, "eval", "view_000.png"))


def test_every_package_folder_is_listed_in_pyproject():
  """A new sub-package missing from pyproject's list installs without its modules (the slow test
  above finds that only after a wheel build); this check names the folder at once."""
  import tomllib
  with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
    listed = set(tomllib.load(f)["tool"]["setuptools"]["packages"])
  folders = set()
  for top, prefix in (("nerf_jax", "nerf_jax"), ("configs", "nerf_jax.configs")):
    for dirpath, _, files in os.walk(os.path.join(ROOT, top)):
      if "__init__.py" in files:
        rel = os.path.relpath(dirpath, os.path.join(ROOT, top))
        folders.add(prefix if rel == "." else prefix + "." + rel.replace(os.sep, "."))
  assert folders == listed, (sorted(folders - listed), sorted(listed - folders))


def test_a_second_checkout_uses_its_own_configs(tmp_path):
  """A second clone (or worktree) put on PYTHONPATH loads its own configs/, not those of the
  checkout installed in the environment (an editable install maps nerf_jax.configs there)."""
  second = tmp_path / "second"
  for folder in ("nerf_jax", "configs"):
    shutil.copytree(os.path.join(ROOT, folder), second / folder,
                    ignore=shutil.ignore_patterns("__pycache__"))
  default = second / "configs" / "default.py"
  default.write_text(default.read_text().replace(
      "  return config\n", "  config.checkout_marker = 'second'  # this copy's own field\n"
      "  return config\n"))
  outside = tmp_path / "elsewhere"
  outside.mkdir()
  code = ("import nerf_jax.configs as c; from nerf_jax.run import config_lib; "
          "print(c.__file__); print(config_lib.load('fast').checkout_marker)")
  res = subprocess.run([sys.executable, "-c", code], cwd=outside, capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(second)), timeout=300)
  assert res.returncode == 0, res.stderr[-2000:]
  path, marker = res.stdout.split()[-2:]
  assert path.startswith(str(second)) and marker == "second", res.stdout
