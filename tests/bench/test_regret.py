"""The regret benchmark (nerf_jax/bench/regret.py, regret_plan.py) on hand-made auto results
and on auto_config's own on a tiny forward-facing scene: each flip run differs from auto's
config in one decision's fields alone (a table written here), the other representations keep
auto's effects, the regret arithmetic, the records and table written and read back, the
picture or the line naming its extra, the command's dry run and its one-line error, and one
tiny end-to-end run of two configs in their own processes.
"""

import json
import os
import subprocess
import sys

import pytest
from absl import flags

from nerf_jax import cli
from nerf_jax.backend import errors
from nerf_jax.bench import records as records_lib
from nerf_jax.bench import regret, regret_plan
from nerf_jax.run import config_lib, experiment, machine
from nerf_jax.run.auto import auto
from nerf_jax.run.auto.rules import cones
from tests.helpers import ROOT

# auto's choices as on a CPU, also when the suite runs on a GPU (conftest.cpu_decisions).
pytestmark = pytest.mark.usefixtures("cpu_decisions")

# The fields each decision may touch, written out here (not read from regret_plan).
CONE_FIELDS = {"model.encoding", "model.grid.antialias", "model.grid.multisample",
               "model.hash.antialias", "model.hash.multisample", "render.march"}
SUBJECT_FIELDS = {"data.subject", "data.photo_bounds", "data.visual_hull", "data.photo_zoom"}
FIELDS = {"background": {"train.random_background"}, "forward": {"data.ndc"},
          "contraction": {"data.contraction"}, "focus": {"data.focus"},
          "appearance": {"model.appearance_dims"},
          "view_dependence": {"model.view_dependent", "auto_by_steps"},
          "cones": CONE_FIELDS, "subject": SUBJECT_FIELDS,
          "photo_bounds": {"data.photo_bounds"}, "visual_hull": {"data.visual_hull"},
          "photo_zoom": {"data.photo_zoom"},
          "transients": {"loss.robust.weight", "train.patch_size", "auto_by_steps"},
          "pose_refinement": {"train.pose_refinement"}, "step_rule": {"auto_by_steps"}}
USER = {"data.scene": "diffuse", "data.image_size": 16, "train.max_seconds": 2.0}


def _decided(chosen, effects):
  """A hand-made auto result: configs/<chosen>.py with `effects` and USER set, auto's lines
  ending in the representation line, the choice recorded (auto_representation)."""
  config = config_lib.load(chosen)
  for name, value in {**USER, **effects}.items():
    config_lib.set_field(config, name, value)
  config.auto = False
  config.auto_decisions = ("an object on a background: ...", f"representation: configs/"
                           f"{chosen}.py")
  config.auto_representation = chosen
  return config


OBJECT = _decided("fast", {"train.random_background": True, "model.appearance_dims": 8,
                           "eval.appearance": "left_half", "model.view_dependent": False})
FORWARD = _decided("llff", {"data.ndc": True, "data.lindisp": False})
CONES = _decided("fast", cones.cone_effects(config_lib.load("fast")))
COLLECTION = _decided("capture", {
    "data.subject": "auto", "data.contraction": "linf", "data.focus": True,
    "data.photo_bounds": True, "data.visual_hull": True, "data.photo_zoom": True,
    "model.appearance_dims": 8, "loss.robust.weight": 1.0, "train.patch_size": 8})

# Effects auto waits to decide until the run knows its step budget (auto.by_steps).
PENDING = _decided("fast", {"model.view_dependent": True, "loss.robust.weight": 1.0,
                            "train.patch_size": 8,
                            "auto_by_steps": ("model.view_dependent", "loss.robust.weight")})


def _diff(a, b):
  """The fields (auto's own aside) whose values differ between ConfigDicts a and b."""
  fa, fb = auto._flat(a), auto._flat(b)  # pylint: disable=protected-access
  return {k for k in fa.keys() | fb.keys() if fa.get(k) != fb.get(k)} - {"auto_decisions"}


@pytest.mark.parametrize("result", [OBJECT, FORWARD, CONES, COLLECTION, PENDING],
                         ids=["object", "forward", "cones", "collection", "pending"])
def test_each_flip_changes_one_decision_alone(result):
  runs, _ = regret_plan.plan(result, USER, 16, 16, "cpu")
  assert runs[0].name == "auto" and not _diff(runs[0].config, result)
  flips = [r for r in runs if r.name.startswith("flip/")]
  assert flips
  for run in flips:
    changed = _diff(run.config, result)
    assert changed and changed <= FIELDS[run.flipped], (run.name, changed)
    assert not run.config.auto and run.config.auto_decisions == ()


def test_autos_own_result_on_a_forward_scene():
  """auto_config itself on a tiny forward-facing scene (not a collection: no warm-up)."""
  config = config_lib.load("auto")
  for name, value in {"data.scene": "forward", "data.image_size": 16,
                      "data.num_views": 8}.items():
    config_lib.set_field(config, name, value)
  result, train_ds, _ = experiment.load_decided(config)
  assert regret_plan.chosen_config(result) == "llff" and result.data.ndc
  runs, skipped = regret_plan.plan(result, USER, train_ds.height, train_ds.width, "cpu")
  flips = {r.flipped: r for r in runs if r.name.startswith("flip/")}
  assert flips["forward"].overrides == {"data.ndc": False}
  for run in flips.values():
    changed = _diff(run.config, result)
    assert changed and changed <= FIELDS[run.flipped], (run.name, changed)
  assert [r.name for r in runs if r.flipped == "representation"] == ["config/capture"]
  assert "flip/contraction: not run (NDC rays take no contraction)" in skipped


def test_flips_turn_what_auto_set_the_other_way():
  flips = {r.flipped: r.overrides for r in regret_plan.plan(COLLECTION, USER, 16, 16, "cpu")[0]
           if r.name.startswith("flip/")}
  assert flips["subject"] == {"data.subject": "", "data.photo_bounds": False,
                              "data.visual_hull": False, "data.photo_zoom": False}
  assert flips["photo_zoom"] == {"data.photo_zoom": False}
  assert flips["contraction"] == {"data.contraction": ""}
  assert flips["focus"] == {"data.focus": False}
  assert flips["appearance"] == {"model.appearance_dims": 0}
  assert flips["transients"] == {"loss.robust.weight": 0.0,
                                 "train.patch_size": config_lib.load("capture").train.patch_size}
  assert flips["pose_refinement"] == {"train.pose_refinement": True}
  assert "forward" not in flips  # NDC on cameras that do not face one way: left out
  cones = {r.flipped: r.overrides for r in regret_plan.plan(CONES, USER, 16, 16, "cpu")[0]}
  assert cones["cones"] == {"model.grid.antialias": False}
  on = {r.flipped: r.overrides for r in regret_plan.plan(OBJECT, USER, 16, 16, "cpu")[0]}
  assert on["cones"]["model.grid.antialias"] is True and on["appearance"] == {
      "model.appearance_dims": 0}
  assert on["transients"] == {"loss.robust.weight": 1.0, "train.patch_size": 16}
  small = {r.flipped: r.overrides for r in regret_plan.plan(OBJECT, USER, 12, 9, "cpu")[0]}
  assert small["transients"]["train.patch_size"] == 9  # a patch lies in one photo
  runs, skipped = regret_plan.plan(OBJECT, USER, 16, 16, "cpu", one_camera=False)
  assert "flip/transients" not in {r.name for r in runs}  # patches need one camera
  assert "flip/transients: not run (its patch batches need images of one camera)" in skipped


def test_the_step_rule_flips_alone_and_the_other_runs_keep_it():
  runs = {r.name: r for r in regret_plan.plan(PENDING, USER, 16, 16, "cpu")[0]}
  rule = runs["flip/step_rule"]
  assert rule.overrides == {"auto_by_steps": ()} and rule.config.model.view_dependent is True
  # A flipped effect is the flip's at any budget; the others still wait for the steps.
  assert runs["flip/view_dependence"].config.auto_by_steps == ("loss.robust.weight",)
  assert runs["flip/transients"].config.auto_by_steps == ("model.view_dependent",)
  for name in ("flip/cones", "flip/appearance", "config/detail", "config/hash"):
    assert runs[name].config.auto_by_steps == PENDING.auto_by_steps, name
  skipped = regret_plan.plan(OBJECT, USER, 16, 16, "cpu")[1]
  assert ("flip/step_rule: not run (auto turned on nothing that pays only from a step count "
          "(auto.MIN_STEPS))") in skipped


def test_representations_that_apply_keep_autos_effects():
  names = lambda result: {r.name for r in regret_plan.plan(result, USER, 16, 16, "cpu")[0]}
  assert {"config/detail", "config/hash", "config/capture"} <= names(OBJECT)
  assert not {"config/fast", "config/llff"} & names(OBJECT)  # auto's own; NDC's
  assert {n for n in names(FORWARD) if n.startswith("config/")} == {"config/capture"}
  assert "config/detail" in names(CONES)  # its density grids take cones too
  assert {n for n in names(OBJECT) if n.startswith("config/")} == {
      "config/detail", "config/hash", "config/capture"}
  for result in (OBJECT, CONES, COLLECTION):
    for run in regret_plan.plan(result, USER, 16, 16, "cpu")[0]:
      if run.flipped != "representation":
        continue
      for field in (*regret_plan.EFFECT_FIELDS, *USER):
        assert (config_lib.get_field(run.config, field) ==
                config_lib.get_field(result, field)), (run.name, field)
      assert cones.has_cones(run.config) == cones.has_cones(result)
      assert not _diff(run.config, regret_plan.with_fields(
          config_lib.load(run.base), run.overrides))


def test_gpu_backend_plans_gpu_configs():
  assert regret_plan.candidates("gpu/lego", "gpu") == {"hash": "hash", "gpu/llff": "llff",
                                                       "capture": "capture"}
  assert regret_plan.candidates("capture", "gpu") == {"gpu/lego": "fast", "hash": "hash",
                                                      "gpu/llff": "llff"}
  forward = _decided("gpu/llff", {"data.ndc": True})
  runs, skipped = regret_plan.plan(forward, USER, 16, 16, "gpu")
  assert [r.name for r in runs if r.flipped == "representation"] == ["config/capture"]
  assert "config/gpu/lego: not run (a box around an object: not for NDC rays)" in skipped


def _record(run, psnr, seconds_per_step, **more):
  return {"scene": "s", "run": run, "flipped": "", "overrides": {}, "psnr": psnr,
          "seconds_per_step": seconds_per_step, **more}


def test_seconds_per_step_leaves_the_compile_out():
  log = [{"step": 10, "wall_seconds": 30.0, "loss": 1.0}, {"step": 20, "wall_seconds": 31.0,
         "loss": 1.0}, {"step": 30, "wall_seconds": 32.0, "loss": 1.0},
         {"step": 30, "wall_seconds": 33.0, "eval_psnr": 20.0}]
  metrics = {"train_seconds": 33.0, "steps": 30}
  assert regret.seconds_per_step(log, metrics) == pytest.approx(0.1)
  assert regret.seconds_per_step(log[:1], metrics) == pytest.approx(1.1)


def test_record_reads_the_scores_the_data_calls_for():
  run = regret_plan.Run("flip/cones", "cones", "fast", {"render.march": True}, None)
  multiscale = {"psnr": 24.0, "ssim": 0.8, "steps": 100, "train_seconds": 10.0,
                "by_scale": {"0": {"psnr": 26.0, "views": 2}, "1": {"psnr": 22.0, "views": 2}},
                "mean_over_scales": {"psnr": 24.5}}
  record = regret.make_record(run, multiscale, "multiscale")
  assert record["by_scale_psnr"] == {"0": 26.0, "1": 22.0}
  assert regret.score(record) == 24.5 and record["lpips"] is None
  assert record["seconds_per_step"] == pytest.approx(0.1)
  collection = {"psnr": 20.0, "ssim": 0.7, "lpips": 0.3, "steps": 10, "train_seconds": 5.0,
                "appearance": "left half: ...", "masks": "masked pixels not scored: ..."}
  record = regret.make_record(run, collection, "crowd")
  assert (record["scored_appearance"], record["scored_masks"]) == (
      "left half: ...", "masked pixels not scored: ...")
  assert regret.score(record) == 20.0 and "by_scale_psnr" not in record
  failed = regret.make_record(run, {"error": "exit status 1: boom"}, "crowd")
  assert failed["error"] == "exit status 1: boom" and regret.score(failed) is None
  # The machine the run measured (its metrics.json's) is the record's; a failed run has none
  # until run_plan stamps it (records.stamp: what the machine is).
  measured = {"cpu_count": 2, "busy": True, "busy_why": "load 3.1 on 2 CPUs"}
  record = regret.make_record(run, {**collection, "machine": measured}, "crowd")
  assert record["machine"] == measured and "machine" not in failed
  assert "flip/cones (busy: load 3.1 on 2 CPUs) |" in regret.table([record], None, "test")


def test_regret_is_best_minus_auto_and_zero_when_auto_is_best():
  records, value = regret.with_regret([_record("auto", 20.0, 0.1), _record("flip/a", 21.5, 0.2),
                                       _record("config/b", 19.0, 0.05)])
  assert value == pytest.approx(1.5)
  assert [r["gain"] for r in records] == pytest.approx([0.0, 1.5, -1.0])
  assert [r["step_cost_ratio"] for r in records] == pytest.approx([1.0, 2.0, 0.5])
  _, value = regret.with_regret([_record("auto", 20.0, 0.1), _record("flip/a", 19.0, 0.1),
                                 {"scene": "s", "run": "flip/b", "error": "boom"}])
  assert value == 0.0
  # Multiscale data: the mean over the scales decides.
  _, value = regret.with_regret([
      _record("auto", 30.0, 0.1, mean_over_scales_psnr=25.0),
      _record("flip/cones", 29.0, 0.1, mean_over_scales_psnr=26.0)])
  assert value == pytest.approx(1.0)
  assert regret.with_regret([{"scene": "s", "run": "auto", "error": "boom"}])[1] is None


def _saved(tmp_path, name, **changes):
  """A run's workdir holding configs/detail.py's config.json with `changes` (dotted fields)."""
  config = config_lib.load("detail")
  for field, value in changes.items():
    config_lib.set_field(config, field, value)
  workdir = tmp_path / name
  workdir.mkdir()
  (workdir / "config.json").write_text(config.to_json())
  return str(workdir)


def test_a_run_that_trained_autos_own_config_is_noise_not_regret(tmp_path):
  # The step rule turned view dependence off: flip/view_dependence trains auto's config again.
  auto_dir = _saved(tmp_path, "auto", **{"model.view_dependent": False, "train.max_steps": 49,
                                         "auto_decisions": ("step rule: ...",)})
  same_dir = _saved(tmp_path, "same", **{"model.view_dependent": False, "train.max_steps": 77})
  other_dir = _saved(tmp_path, "other", **{"model.view_dependent": True})
  trained = [regret.trained_config(d) for d in (auto_dir, same_dir, other_dir)]
  assert trained[0] == trained[1] != trained[2]
  assert regret.trained_config(str(tmp_path)) is None  # no config.json
  records, value = regret.with_regret([
      _record("auto", 20.0, 0.1, trained=trained[0]),
      _record("flip/view_dependence", 23.0, 0.1, trained=trained[1]),
      _record("flip/step_rule", 19.0, 0.1, trained=trained[2])])
  assert [r.get("same_as_auto") for r in records] == [None, True, False]
  assert value == 0.0 and records[1]["gain"] == pytest.approx(3.0)
  regret.write_results(records, value, str(tmp_path), "cmd")
  table = (tmp_path / "table.md").read_text()
  assert "(best: auto)" in table and "| flip/view_dependence (auto's config) |" in table


def test_results_and_table_round_trip(tmp_path):
  records, value = regret.with_regret([
      _record("auto", 20.0, 0.1, steps=10, ssim=0.8, lpips=None),
      _record("flip/a", 21.0, 0.2, steps=5, ssim=0.85, lpips=0.2,
              overrides={"train.random_background": False}),
      {"scene": "s", "run": "config/c", "flipped": "representation", "overrides": {},
       "error": "ValueError: boom"}])
  regret.write_results(records, value, str(tmp_path), "python -m nerf_jax.bench.regret")
  back = records_lib.read(str(tmp_path / "results.jsonl"))
  assert back == [{**r, "regret": value} for r in records]
  table = (tmp_path / "table.md").read_text().splitlines()
  assert "Auto's regret: 1.00 dB (best: flip/a)." in table
  rows = [l for l in table if l.startswith("| ") and not l.startswith("| run")]
  assert len(rows) == 3
  assert rows[1].split(" | ")[2:6] == ["train.random_background=False", "21.00", "-", "+1.00"]
  assert "ValueError: boom" in rows[2]


def test_picture_or_the_line_naming_the_extra(tmp_path):
  records, value = regret.with_regret([_record("auto", 20.0, 0.1), _record("flip/a", 21.0, 0.2)])
  problem = regret.picture(records, value, str(tmp_path / "regret_s.png"))
  if problem:
    assert "[bench]" in problem
  else:
    assert (tmp_path / "regret_s.png").stat().st_size > 0


def test_no_matplotlib_names_the_extra(monkeypatch, tmp_path):
  monkeypatch.setattr(regret.report, "missing_dependency", lambda: regret.report.MISSING_MATPLOTLIB)
  records, value = regret.with_regret([_record("auto", 20.0, 0.1)])
  assert regret.picture(records, value, str(tmp_path / "p.png")) == (
      'plots need matplotlib: pip install -e ".[bench]"')
  assert not (tmp_path / "p.png").exists()


def test_dry_run_prints_the_plan_and_trains_nothing(monkeypatch, tmp_path, capsys):
  seen = {}

  def decided(config):  # auto's decision stands in for the data's (its warm-up takes minutes)
    seen["config"] = config
    return OBJECT, type("Data", (), {"height": 16, "width": 16, "image_cameras": None})(), None

  monkeypatch.setattr(experiment, "load_decided", decided)
  given = ["nerf_jax.bench.regret", "--scene=glossy", "--seconds=3", f"--out={tmp_path}",
           "--dry_run", "--config.data.image_size=16"]
  resolved, spec = cli.resolve_config_argv(regret.standard.normalised_argv(given))
  values = flags.FlagValues()
  regret.define_regret_flags(values, resolved)
  errors.parse_flags(resolved, values)
  assert regret.regret(values, spec, given) == ([], None)
  printed = capsys.readouterr().out
  config = seen["config"]
  assert config.auto and config.data.scene == "glossy" and config.train.max_seconds == 3.0
  assert {"data.image_size", "data.scene", "train.max_seconds"} <= set(config.auto_flags)
  assert "runs of 3 s of training each" in printed
  assert "  flip/appearance (fast): --config.model.appearance_dims=0" in printed
  assert "config/llff: not run" in printed
  assert os.listdir(tmp_path) == []


def test_runs_keeps_the_named_runs_in_the_plans_order():
  runs, _ = regret_plan.plan(OBJECT, USER, 16, 16, "cpu")
  names = [r.name for r in runs]
  assert regret.chosen(runs, []) == runs
  picked = regret.chosen(runs, ["flip/background", "auto"])
  assert [r.name for r in picked] == ["auto", "flip/background"]
  assert [r.name for r in regret.chosen(runs, [names[-1]])] == [names[-1]]
  with pytest.raises(ValueError, match="--runs: flip/nope is not a planned run"):
    regret.chosen(runs, ["auto", "flip/nope"])


def test_runs_with_a_minus_leave_those_out_even_where_the_plan_has_none():
  runs, _ = regret_plan.plan(OBJECT, USER, 16, 16, "cpu")
  names = [r.name for r in runs]
  kept = regret.chosen(runs, [f"-{names[1]}", "-flip/not_in_this_plan"])
  assert [r.name for r in kept] == names[:1] + names[2:]
  with pytest.raises(ValueError, match="not both"):
    regret.chosen(runs, ["auto", f"-{names[1]}"])


def test_dry_run_from_the_command_line_exits_0():
  proc = subprocess.run([sys.executable, "-m", "nerf_jax.bench.regret", "--scene=forward",
                         "--config.data.image_size=16", "--config.data.num_views=8",
                         "--seconds=5", "--out=unused", "--dry_run"], cwd=ROOT,
                        capture_output=True, text=True, check=False,  # auto's CPU plan:
                        env={**os.environ, "PYTHONPATH": ROOT, "JAX_PLATFORMS": "cpu"})
  assert proc.returncode == 0, proc.stderr
  assert "auto: representation: configs/llff.py" in proc.stdout
  assert "runs of 5 s of training each, into unused:" in proc.stdout
  assert "  flip/forward (llff): --config.data.ndc=False" in proc.stdout
  assert not os.path.exists(os.path.join(ROOT, "unused"))


def test_bad_scene_is_one_line_and_status_1():
  proc = subprocess.run([sys.executable, "-m", "nerf_jax.bench.regret", "--scene=nope",
                         "--dry_run"], cwd=ROOT, capture_output=True, text=True, check=False,
                        env={**os.environ, "PYTHONPATH": ROOT})
  assert proc.returncode == 1
  assert proc.stderr.strip().splitlines() == [
      proc.stderr.strip()] and "unknown scene 'nope'" in proc.stderr
  assert "Traceback" not in proc.stderr + proc.stdout


@pytest.mark.slow  # two tiny trainings, each in its own process
def test_two_tiny_runs_end_to_end(tmp_path):
  tiny = {"data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5, "num_samples": 8,
          "model.grid.resolutions": (8, 16), "model.width": 16, "train.batch_rays": 64,
          "train.max_steps": 3, "train.log_every": 1, "train.checkpoint_every": 3,
          "train.eval_every": 0, "render.chunk": 256, "render.march": False,
          "train.max_seconds": 0.0, "render.after_training": False}
  result = _decided("fast", {**tiny, "train.random_background": True})
  runs = [r for r in regret_plan.plan(result, tiny, 16, 16, "cpu")[0]
          if r.name in ("auto", "flip/background")]
  records, value = regret.run_plan(runs, "diffuse", str(tmp_path), "test")
  assert [r["run"] for r in records] == ["auto", "flip/background"]
  for record in records:
    assert "error" not in record, record
    assert record["steps"] == 3 and record["psnr"] > 0
  saved = json.loads((tmp_path / "flip_background" / "config.json").read_text())
  assert saved["train"]["random_background"] is False
  assert records[0]["step_cost_ratio"] == 1.0
  log = records_lib.read(str(tmp_path / "auto" / "metrics.jsonl"))
  assert records[0]["seconds_per_step"] == pytest.approx(
      (log[2]["wall_seconds"] - log[0]["wall_seconds"]) / 2)  # steps 1 to 3: no compile
  assert value == max(0.0, records[1]["psnr"] - records[0]["psnr"])
  assert len(records_lib.read(str(tmp_path / "results.jsonl"))) == 2
  for record, name in zip(records, ("auto", "flip_background")):  # measured in the run's process
    metrics = json.loads((tmp_path / name / "metrics.json").read_text())
    assert record["machine"] == metrics["machine"] and metrics["machine"]["cpu_count"] >= 1
    assert record["date"].endswith(" UTC") and record["git"] == machine.git_revision()
  with pytest.raises(ValueError, match="auto holds an earlier run"):  # it would resume
    regret.run_plan(runs, "diffuse", str(tmp_path), "test")


def test_a_data_folder_replaces_the_scene_and_must_exist(tmp_path):
  base = config_lib.load("auto")
  config, user = regret.scene_config(base, "mine", str(tmp_path), 5.0)
  assert config.data.path == str(tmp_path) and config.data.scene == base.data.scene
  assert user == {"data.path": str(tmp_path), "train.max_seconds": 5.0,
                  "render.after_training": False}
  with pytest.raises(FileNotFoundError, match="--data_path=.*nowhere: not found"):
    regret.scene_config(base, "mine", str(tmp_path / "nowhere"), 5.0)
