"""The viewer's command line (`python -m nerf_jax.viewer`, `nerf-view`): its own main, the one-line
errors of restoring a run, as nerf-render's."""

import os
import subprocess
import sys
import tomllib

from nerf_jax import cli
from nerf_jax.viewer import __main__ as viewer_main
from tests.helpers import ROOT


def test_the_viewer_turns_the_errors_nerf_render_does_into_one_line():
  assert set(viewer_main.USER_ERRORS) == set(cli.USER_ERRORS)


def test_nerf_view_is_the_viewers_main():
  with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
    scripts = tomllib.load(f)["project"]["scripts"]
  module, name = scripts["nerf-view"].split(":")
  assert module == "nerf_jax.viewer.__main__" and getattr(viewer_main, name) is viewer_main.main


def test_a_workdir_without_a_run_is_one_line_and_status_1(tmp_path):
  res = subprocess.run([sys.executable, "-m", "nerf_jax.viewer", f"--workdir={tmp_path / 'gone'}",
                        "--port=0"], cwd=ROOT, capture_output=True, text=True, timeout=300)
  lines = res.stderr.strip().splitlines()
  assert res.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: "), res.stderr
  assert "gone" in lines[0]
