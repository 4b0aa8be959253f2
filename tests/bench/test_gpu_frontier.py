"""The GPU session's script (bench/gpu_frontier.py): its plan and report from made-up records,
and the whole script on the CPU at tiny sizes (--smoke), as the GPU session will run it."""

import json
import subprocess
import sys

import pytest

from nerf_jax.bench import gpu_frontier

from tests.bench.test_records import assert_stamped
from tests.helpers import ROOT


def test_seconds_per_scene_default_to_the_goals_and_can_be_set():
  assert gpu_frontier.parse_seconds([]) == {"lego": 60.0, "fox": 60.0, "fern": 120.0}
  assert gpu_frontier.parse_seconds(["lego=300"])["lego"] == 300.0
  with pytest.raises(ValueError, match="--seconds=chair=5"):
    gpu_frontier.parse_seconds(["chair=5"])


def test_a_scene_runs_its_gpu_config_on_its_folder():
  name, fields = gpu_frontier.scene_config("fox", "/data/fox", 60.0, smoke=False)
  assert name == "gpu/capture"
  assert fields["data.path"] == "/data/fox" and fields["data.factor"] == 4
  assert fields["train.max_seconds"] == 60.0 and fields["render.video_frames"] == 0
  name, fields = gpu_frontier.scene_config("fern", "", 0.0, smoke=True)
  assert name == "gpu/llff" and fields["data.scene"] == "forward" and fields["data.path"] == ""
  assert fields["train.max_steps"] == 3


def test_fields_set_one_scenes_config_with_literal_values():
  fields = gpu_frontier.parse_fields(["lego:data.half_res=True", "lego:train.lr=5e-3",
                                      "fern:model.grid.resolutions=(8,16)",
                                      "fox:model.hash.gather_dtype=bfloat16"])
  assert fields == {"lego": {"data.half_res": True, "train.lr": 5e-3},
                    "fern": {"model.grid.resolutions": (8, 16)},
                    "fox": {"model.hash.gather_dtype": "bfloat16"}}
  with pytest.raises(ValueError, match="--fields=lego:train.lr"):
    gpu_frontier.parse_fields(["lego:train.lr"])


def _record(test_psnr, **psnr_at):
  return {"test_psnr": test_psnr, "test_ssim": 0.9, "steps": 1000, "step_ms": 2.5,
          "render_ms": 40.0, "psnr_at": {k[1:]: v for k, v in psnr_at.items()}}


def test_goals_are_met_short_or_not_measured():
  lines = gpu_frontier.goal_lines("lego", _record(35.5, s15=30.0, s30=33.0), 60.0)
  assert lines == ["≥ 35.0 dB at 60 s: 35.50 dB (all test views): met",
                   "≥ 36.0 dB at 300 s: not measured (the run lasted 60 s)"]
  lines = gpu_frontier.goal_lines("fox", _record(27.0, s60=27.9, s120=28.0), 120.0)
  assert lines == ["≥ 28.5 dB at 60 s: 27.90 dB (probe views, within the longer run): "
                   "short by 0.60 dB"]


def test_the_table_says_how_the_sample_budget_was_used():
  lego = {**_record(34.0, s60=33.9), "last_step_stats": {
      "colour/rays_in_loss": 20000, "colour/samples_wanted": 393216},
          "config": {"train": {"batch_rays": 32768, "sample_budget": 262144}}}
  lines = gpu_frontier.scene_table({"lego": ("gpu/lego", 60.0, lego)}, "gpu")
  assert ("- lego: the last step's budget: 20,000 of 32,768 drawn rays in the loss; they asked "
          "for 393,216 samples, 1.50× the budget of 262,144") in lines
  no_budget = {**_record(25.0), "last_step_stats": {"colour/psnr": 25.0},
               "config": {"train": {"batch_rays": 4096, "sample_budget": 0}}}
  assert gpu_frontier.budget_line(no_budget) is None


def test_the_table_has_a_row_per_scene_and_names_an_error():
  results = {"lego": ("gpu/lego", 60.0, _record(34.0, s15=30.0, s30=32.0, s60=33.9)),
             "fern": ("gpu/llff", 0.0, {"error": "skipped: 20 s left"})}
  lines = gpu_frontier.scene_table(results, "gpu | NVIDIA H200 | jax 0.11.2")
  rows = [l for l in lines if l.startswith("| lego") or l.startswith("| fern")]
  assert rows[0].startswith("| lego | gpu/lego | 60 | 1,000 | 2.50 | 30.00 | 32.00 | 33.90 |")
  assert rows[1].endswith("skipped: 20 s left |")
  assert "- lego: ≥ 35.0 dB at 60 s: 34.00 dB (all test views): short by 1.00 dB" in lines


@pytest.mark.slow
def test_the_script_runs_end_to_end_on_the_cpu_when_shrunk(tmp_path):
  """--smoke: lego's config shrunk on the built-in diffuse scene, then the profile and the
  scatter-add check (about a minute and a half on 2 cores)."""
  out = tmp_path / "out"
  res = subprocess.run([sys.executable, "-m", "nerf_jax.bench.gpu_frontier", "--smoke",
                        "--scenes=lego", f"--out={out}"], cwd=ROOT, capture_output=True,
                       text=True, timeout=600, check=False)
  assert res.returncode == 0, res.stderr[-3000:]
  report = json.load(open(out / "frontier.json"))
  record = report["scenes"]["lego"]["record"]
  assert "error" not in record, record.get("error")
  assert record["steps"] == 3 and record["test_psnr"] > 0
  assert record["last_step_stats"]["colour/samples_wanted"] > 0  # the budget's use, in the report
  assert all(stage["status"].startswith("exit 0") for stage in report["stages"].values())
  text = (out / "frontier.md").read_text()
  assert "- lego: the last step's budget: " in text
  assert "| lego | gpu/lego |" in text and "| train step (all) |" in text
  assert "| one row |" in text and json.load(open(out / "scatter.json"))["rows"]
  assert_stamped(report, record["machine"])  # the machine the scene's child measured
  assert_stamped(json.load(open(out / "scatter.json")))
