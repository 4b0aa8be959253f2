"""bench.regret_table: the scenes' commands, the workers pinned to their cores, and the table of
every scene's gains built from results.jsonl files written here by bench.regret's writer."""

import json
import os
import subprocess
import sys

import pytest

from nerf_jax.bench import regret, regret_table


def _record(scene, run, psnr, overrides=None, flipped=None, spt=0.1):
  return {"scene": scene, "run": run, "flipped": flipped if flipped is not None else
          ("" if run == "auto" else run.split("/")[1]), "base": "fast",
          "overrides": overrides or {}, "psnr": psnr, "steps": 100, "seconds": 60.0,
          "seconds_per_step": spt, "machine": {"backend": "cpu"}}


def _write(out, scene, records):
  records, value = regret.with_regret(records)
  regret.write_results(records, value, os.path.join(out, scene), "python -m ...")


def test_each_scene_command_gets_the_overrides_and_the_runs():
  argv = ["regret_table", "--config=auto", "--config.eval.fit_steps=100", "--scenes=fog",
          "--workers=1"]
  passed = regret_table.passed_on(argv, [])
  assert passed == ["--config=auto", "--config.eval.fit_steps=100", "--runs=-config/hash"]
  command = regret_table.scene_command("fog", 60.0, "runs/t", passed)
  assert command[1:5] == ["-m", "nerf_jax.bench.regret", "--scene=fog", "--seconds=60"]
  assert f"--out={os.path.join('runs/t', 'fog')}" in command
  assert regret_table.passed_on(argv, ["auto", "flip/cones"])[-1] == "--runs=auto,flip/cones"


def test_workers_are_pinned_to_one_core_each_where_there_are_enough(tmp_path):
  allowed = sorted(os.sched_getaffinity(0))
  assert regret_table.cores(len(allowed) + 1) == [None] * (len(allowed) + 1)
  assert regret_table.cores(1) == [{allowed[0]}]
  probe = [sys.executable, "-c", "import os; print(sorted(os.sched_getaffinity(0)))"]
  status = regret_table.run_scenes({"a": probe, "b": probe}, str(tmp_path), 1)
  assert status == {"a": 0, "b": 0}
  for scene in ("a", "b"):
    assert (tmp_path / f"{scene}.log").read_text().strip() == str([allowed[0]])


def test_the_table_gives_each_scene_its_regret_and_each_flip_its_direction_and_gain(tmp_path):
  _write(str(tmp_path), "glossy", [
      _record("glossy", "auto", 20.0),
      _record("glossy", "flip/view_dependence", 18.0, {"model.view_dependent": False}, spt=0.07),
      _record("glossy", "flip/cones", 20.5, {"model.grid.antialias": True}, spt=0.2),
      _record("glossy", "config/detail", 19.0, {}, flipped="representation")])
  _write(str(tmp_path), "fern", [
      _record("fern", "auto", 22.0),
      _record("fern", "flip/cones", 21.0, {"model.encoding": "posenc"})])
  rows = regret_table.summarize(str(tmp_path))
  glossy = next(r for r in rows if r["scene"] == "glossy")
  assert glossy["regret"] == pytest.approx(0.5) and glossy["best_run"] == "flip/cones"
  assert glossy["runs"]["flip/view_dependence"]["turned"] == "off"
  assert glossy["runs"]["flip/cones"]["turned"] == "on"
  assert glossy["runs"]["config/detail"]["turned"] == ""
  fern = next(r for r in rows if r["scene"] == "fern")
  assert fern["regret"] == 0.0 and fern["runs"]["flip/cones"]["turned"] == "off"
  table = (tmp_path / "table.md").read_text()
  head = table.splitlines()[0]
  assert head.index("flip/view_dependence") < head.index("flip/cones") < head.index(
      "config/detail")  # flips in regret_plan.FLIPS's order, then the representations
  assert "| off -2.00 (0.70×) |" in table and "| on +0.50 (2.00×) |" in table
  assert len([json.loads(l) for l in open(tmp_path / "summary.jsonl")]) == 2
  assert (tmp_path / "regret_table.png").stat().st_size > 1000


def test_nothing_to_summarise_is_one_line(tmp_path):
  with pytest.raises(FileNotFoundError, match="no <scene>/results.jsonl"):
    regret_table.summarize(str(tmp_path))


def test_summarize_from_the_command_line(tmp_path):
  _write(str(tmp_path), "fog", [_record("fog", "auto", 20.0),
                                _record("fog", "flip/background", 19.0,
                                        {"train.random_background": False})])
  proc = subprocess.run([sys.executable, "-m", "nerf_jax.bench.regret_table", "--summarize",
                         f"--out={tmp_path}"], capture_output=True, text=True, check=False)
  assert proc.returncode == 0, proc.stderr
  assert "1 scenes ->" in proc.stdout and "| fog | fast.py | 20.00 |" in (
      tmp_path / "table.md").read_text()
  empty = subprocess.run([sys.executable, "-m", "nerf_jax.bench.regret_table", "--summarize",
                          f"--out={tmp_path / 'none'}"], capture_output=True, text=True,
                         check=False)
  assert empty.returncode == 1 and "Traceback" not in empty.stderr


def test_a_run_of_autos_own_config_shows_as_noise_and_is_never_the_best(tmp_path):
  _write(str(tmp_path), "glossy", [
      {**_record("glossy", "auto", 20.0), "trained": "a"},
      {**_record("glossy", "flip/view_dependence", 23.0, {"model.view_dependent": False}),
       "trained": "a"},
      {**_record("glossy", "flip/step_rule", 19.0, {"auto_by_steps": []}), "trained": "b"}])
  row = regret_table.summarize(str(tmp_path))[0]
  assert row["regret"] == 0.0 and row["best_run"] == "auto"
  table = (tmp_path / "table.md").read_text()
  assert "| = auto +3.00 |" in table and "| off -1.00 (1.00×) |" in table


def test_a_scene_names_the_runs_whose_machine_was_busy(tmp_path):
  busy = {"backend": "cpu", "busy": True, "busy_why": "load 3.1 on 2 CPUs"}
  _write(str(tmp_path), "fog", [
      _record("fog", "auto", 20.0),
      {**_record("fog", "flip/background", 19.0, {"train.random_background": False}),
       "machine": busy}])
  _write(str(tmp_path), "glossy", [_record("glossy", "auto", 20.0)])
  rows = {r["scene"]: r for r in regret_table.summarize(str(tmp_path))}
  assert rows["fog"]["busy_runs"] == ["flip/background"] and rows["glossy"]["busy_runs"] == []
  table = (tmp_path / "table.md").read_text()
  assert "| fog (busy: flip/background) | fast.py |" in table and "| glossy | fast.py |" in table
