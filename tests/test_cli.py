"""Bad input gets one clear line and exit status 1, through the entry points' own code paths.

Most cases run in-process (`cli.run_main` around `cli.train` / `outputs.render`,
`cli.resolve_config_argv` and `errors.parse_flags` on a private FlagValues); a few run `train.py`,
`render.py` in a subprocess.
"""

import copy
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from absl import flags, logging
from ml_collections import config_flags

from nerf_jax import cli
from nerf_jax.backend import errors
from nerf_jax.evaluate import evaluation
from nerf_jax.run import config_lib, experiment, outputs
from nerf_jax.run.signature import model_signature, state_template
from nerf_jax.train import checkpoints
from nerf_jax.configs import debug, default
from nerf_jax.data import DataError
from tests.helpers import shipped_configs
from tests.helpers import blender_folder as _blender
from tests.helpers import small_config

from tests.helpers import ROOT

TWO_STEPS = {"train.max_steps": 2}  # the debug config, 2 steps


def _one_line_error(capsys, fn, *parts):
  """Run fn under cli.run_main; assert exit 1 and a single 'error: ' line containing `parts`."""
  capsys.readouterr()
  with pytest.raises(SystemExit) as info:
    cli.run_main(fn)
  assert info.value.code == 1
  lines = capsys.readouterr().err.strip().splitlines()
  assert len(lines) == 1 and lines[0].startswith("error: "), lines
  for part in parts:
    assert part in lines[0], (part, lines[0])
  return lines[0]


def _train_fails(capsys, tmp_path, config, *parts):
  return _one_line_error(capsys, lambda: cli.train(config, str(tmp_path / "run")), *parts)


def _poses(num):
  poses = np.tile(np.eye(4, dtype=np.float32), (num, 1, 1))
  poses[:, 2, 3] = 4.0  # 4 units back along +z, looking down -z at the origin
  return poses


def _npz(tmp_path, name="data.npz", num=4, size=(6, 6), **arrays):
  """A tiny .npz; `arrays` replace (or with None remove) images, poses, focal."""
  rng = np.random.default_rng(0)
  base = {"images": rng.uniform(size=(num, *size, 3)).astype(np.float32), "poses": _poses(num),
          "focal": np.float32(8.0)}
  base.update(arrays)
  path = str(tmp_path / name)
  np.savez(path, **{k: v for k, v in base.items() if v is not None})
  return path


# --- data ---------------------------------------------------------------------------------------

def _on(path):
  """The debug config, 2 steps, on the data at `path`."""
  return small_config({**TWO_STEPS, "data.path": path})


def test_missing_path_and_unknown_format(capsys, tmp_path):
  _train_fails(capsys, tmp_path, _on(str(tmp_path / "nope.npz")), "nope.npz", "no such")
  (tmp_path / "notes.txt").write_text("hi")
  _train_fails(capsys, tmp_path, _on(str(tmp_path / "notes.txt")), "notes.txt",
               "unknown dataset format")


@pytest.mark.parametrize("key", ["images", "poses", "focal"])
def test_npz_missing_array(capsys, tmp_path, key):
  path = _npz(tmp_path, **{key: None})
  _train_fails(capsys, tmp_path, _on(path), "data.npz", f"missing array '{key}'")


def test_npz_bad_contents(capsys, tmp_path):
  cases = [
      ({"poses": _poses(3)}, ["'poses' has 3", "4 views"]),
      ({"poses": np.zeros((4, 3, 3))}, ["'poses'", "(4, 3, 3)", "[N, 4, 4] or [N, 3, 4]"]),
      ({"images": np.zeros((4, 6, 6, 2))}, ["'images'", "channels", "3 (RGB) or 4 (RGBA)"]),
      ({"images": np.full((4, 6, 6, 3), 255.0)}, ["'images'", "expected [0, 1]"]),
      ({"images": np.full((4, 6, 6, 3), np.nan)}, ["'images'", "NaN"]),
      ({"images": np.full((4, 6, 6, 3), np.inf)}, ["'images'", "NaN or inf"]),
  ]
  for i, (arrays, parts) in enumerate(cases):
    path = _npz(tmp_path, f"bad{i}.npz", **arrays)
    _train_fails(capsys, tmp_path, _on(path), f"bad{i}.npz", *parts)


def test_blender_errors(capsys, tmp_path):
  meta = str(tmp_path / "transforms_train.json")
  _train_fails(capsys, tmp_path, _on(_blender(tmp_path, text='{"frames": [\n')),
               meta, "malformed JSON", "line 2")
  _train_fails(capsys, tmp_path, _on(_blender(tmp_path, {"camera_angle_x": None})),
               meta, "'camera_angle_x'")
  missing = {"frames": [{"file_path": "./r_9.png", "transform_matrix": np.eye(4).tolist()}]}
  _train_fails(capsys, tmp_path, _on(_blender(tmp_path, missing)),
               meta, "frames[0].file_path", "r_9.png", "not found")


def test_llff_table_of_the_wrong_shape(capsys, tmp_path):
  (tmp_path / "images").mkdir()
  np.save(tmp_path / "poses_bounds.npy", np.zeros((3, 15)))
  _train_fails(capsys, tmp_path, _on(str(tmp_path)), "poses_bounds.npy", "(3, 15)",
               "[N, 17]")


def test_holdout_out_of_range(capsys, tmp_path):
  _train_fails(capsys, tmp_path, small_config({**TWO_STEPS, "data.holdout_from": 12}),
               "holdout_from=12", "empty")


# --- checkpoints, workdirs and what a run writes --------------------------------------------------

@pytest.fixture(scope="module")
def trained(tmp_path_factory):
  """A 2-step run, logging and evaluating every step, on an .npz of odd, non-square images with
  [N, 3, 4] poses (shared by the tests below, which only read it): (workdir, config, result)."""
  root = tmp_path_factory.mktemp("trained")
  path = _npz(root, num=5, size=(7, 11), poses=_poses(5)[:, :3])
  config = small_config({**TWO_STEPS, "data.path": path, "data.holdout_from": 4})
  config.train.log_every = config.train.eval_every = 1
  result = cli.train(config, str(root / "run"))
  return root / "run", config, result


def test_odd_non_square_images_and_3x4_poses_train(trained):
  """Odd, non-square sizes and [N, 3, 4] poses are valid input, not errors."""
  workdir, _, result = trained
  assert np.isfinite(result["psnr"]) and result["steps"] == 2
  assert json.loads((workdir / "metrics.json").read_text())["per_view"] == result["per_view"]


def _events(workdir):
  """{tag: [step, ...]} of the TensorBoard event files in workdir/tb (a TFRecord reader)."""
  from tensorboardX.proto import event_pb2  # pylint: disable=import-outside-toplevel
  tags = {}
  for name in os.listdir(workdir / "tb"):
    data = (workdir / "tb" / name).read_bytes()
    pos = 0
    while pos < len(data):
      length = int.from_bytes(data[pos:pos + 8], "little")
      event = event_pb2.Event.FromString(data[pos + 12:pos + 12 + length])
      pos += 12 + length + 4  # length, its crc, the record, its crc
      for value in event.summary.value:
        tags.setdefault(value.tag, []).append(event.step)
  return tags


def test_run_writes_tensorboard_events_and_json_logs(trained):
  workdir, config, _ = trained
  tags = _events(workdir)
  for tag in ("train/loss", "train/psnr", "train/learning_rate", "train/rays_per_second",
              "eval/psnr"):
    assert tags[tag] == [1, 2], (tag, tags)
  for tag in ("eval/rgb", "eval/depth", "eval/truth"):
    assert 2 in tags[tag], (tag, tags)
  assert tags["test/psnr"] == [2]
  records = [json.loads(l) for l in (workdir / "metrics.jsonl").read_text().splitlines()]
  assert [r["step"] for r in records] == [1, 2, 2] and "eval_psnr" in records[1]
  assert records[2]["final"] and "eval_ssim" in records[2]
  # The wall time spent travels inside the checkpoint (no separate, non-atomic progress file).
  template = state_template(experiment.setup(config))
  _, meta = checkpoints.restore_with_meta(checkpoints.latest_path(str(workdir)), template,
                                          model_signature(config))
  assert meta["wall_seconds"] > 0 and not (workdir / "progress.json").exists()


def test_incompatible_workdir_is_refused_and_left_alone(capsys, trained):
  workdir, config, _ = trained
  tmp_path = workdir.parent
  before = {p: (workdir / p).read_bytes() for p in ("config.json", "checkpoints/ckpt_2.msgpack")}
  wider = copy.deepcopy(config)
  wider.model.width = 48
  _train_fails(capsys, tmp_path, wider, "ckpt_2.msgpack", "incompatible config",
               "width: checkpoint 32 vs config 48", "new --workdir")
  clipped = copy.deepcopy(config)
  clipped.train.grad_clip = 1.0  # another optimizer state structure
  _train_fails(capsys, tmp_path, clipped, "ckpt_2.msgpack", "grad_clip", "new --workdir")
  assert {p: (workdir / p).read_bytes() for p in before} == before  # nothing overwritten
  assert checkpoints.list_steps(str(workdir)) == [2]


def test_damaged_checkpoint_is_named(capsys, tmp_path, trained):
  workdir = tmp_path / "run"
  shutil.copytree(trained[0], workdir)
  (workdir / "checkpoints" / "ckpt_2.msgpack").write_bytes(b"\x00garbage")
  _train_fails(capsys, tmp_path, trained[1], "ckpt_2.msgpack", "unreadable checkpoint")


def test_render_needs_a_workdir_with_a_checkpoint(capsys, tmp_path):
  _one_line_error(capsys, lambda: outputs.render(str(tmp_path / "none"), "eval"),
                  "none", "no such directory")
  _one_line_error(capsys, lambda: outputs.render(str(tmp_path), "eval"),
                  "config.json not found")
  (tmp_path / "config.json").write_text(small_config(TWO_STEPS).to_json())
  _one_line_error(capsys, lambda: outputs.render(str(tmp_path), "eval"),
                  "no checkpoint", "train first")


# --- flags and config overrides -----------------------------------------------------------------

def _parse(capsys, *args):
  """cli.resolve_config_argv + errors.parse_flags on a private FlagValues with the config flag, as
  train_main does; returns (flag values, the one error line or None)."""
  values = flags.FlagValues()
  capsys.readouterr()
  try:
    argv, _ = cli.resolve_config_argv(["train.py", *args])
    config_flags.DEFINE_config_file("config", config_lib.resolve("debug"), "",
                                    flag_values=values, lock_config=True, sys_argv=argv)
    errors.parse_flags(argv, values)
    values.config.seed  # the config flag loads lazily  # pylint: disable=pointless-statement
  except SystemExit as e:
    assert e.code == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return values, lines[0]
  return values, None


def test_config_overrides(capsys):
  cfg = f"--config={os.path.join(ROOT, 'configs', 'debug.py')}"
  values, error = _parse(capsys, cfg, "--config.data.holdout_from=3")
  assert error is None and values.config.data.holdout_from == 3
  _, error = _parse(capsys, cfg, "--config.data.bogus=1")
  assert "--config.data.bogus" in error and "config.data has no field 'bogus'" in error
  assert "holdout_from" in error  # lists the valid fields
  _, error = _parse(capsys, cfg, "--config.bogus.x=1")
  assert "config has no field 'bogus'" in error
  _, error = _parse(capsys, cfg, "--config.train.max_steps=1.5")
  assert "--config.train.max_steps=1.5" in error and "int" in error
  _, error = _parse(capsys, "--config=nope/missing.py")
  assert "--config=nope/missing.py: no such config file or name" in error
  _, error = _parse(capsys, cfg, "stray")
  assert "unexpected argument 'stray'" in error
  _, error = _parse(capsys, "--workdir=x")
  assert "workdir" in error


def test_config_by_name_from_anywhere(capsys, tmp_path, monkeypatch):
  """`--config=fast` and `--config=scenes/fog` name installed configs from any directory."""
  monkeypatch.chdir(tmp_path)
  values, error = _parse(capsys, "--config=fast", "--config.train.max_steps=7")
  assert error is None and values.config.model.encoding == "grid"
  assert values.config.train.max_steps == 7
  values, error = _parse(capsys, "--config=scenes/fog")
  assert error is None and values.config.data.scene == "fog"
  (tmp_path / "broken.py").write_text("def get_config():\n  return 1 / 0\n")
  _, error = _parse(capsys, "--config=broken.py")
  assert error == "error: --config=broken.py: cannot load the config file (ZeroDivisionError: " \
                  "division by zero)"


def test_saved_config_is_completed_with_todays_defaults(tmp_path):
  """A config.json written before a field existed gets the default's value for it, once."""
  saved = small_config(TWO_STEPS).to_dict()
  del saved["render"]["march"], saved["model"]["encoding"]
  saved["model"]["skip_layers"] = [1]  # JSON has no tuples
  (tmp_path / "config.json").write_text(json.dumps(saved))
  config = config_lib.load_saved(str(tmp_path))
  assert config.render.march == default.get_config().render.march
  assert config.model.encoding == "posenc" and config.model.skip_layers == (1,)
  assert config.train.max_steps == 2  # the saved values win


# A value for every renamed field (config_lib.RENAMED), none of them the default's.
OLD_SPELLINGS = {"model.grid_resolutions": (8, 16), "model.grid_features": 2,
                 "model.hash_levels": 4, "model.hash_log2_size": 10, "model.hash_features": 4,
                 "model.hash_base_resolution": 4, "model.hash_max_resolution": 64,
                 "model.hash_dtype": "float16", "train.coarse_loss_weight": 0.5,
                 "train.huber_delta": 0.05, "train.distortion_weight": 0.01,
                 "train.pose_prior": 1.5, "train.tv_weight": 0.02,
                 "render.appearance_protocol": "left_half"}


def _parent(tree, field):
  """(the mapping holding dotted `field` in `tree`, the field's last name)."""
  *path, name = field.split(".")
  for part in path:
    tree = tree[part]
  return tree, name


def test_old_spellings_cover_every_renamed_field_with_a_value_not_the_default():
  assert set(OLD_SPELLINGS) == set(config_lib.RENAMED)
  defaults = default.get_config()
  for old, value in OLD_SPELLINGS.items():
    section, name = _parent(defaults, config_lib.renamed(old))
    assert section[name] != value, old


def test_renamed_fields_on_the_command_line_give_the_new_names_config(capsys):
  """--config.model.grid_resolutions=... (the old name) loads the config that
  --config.model.grid.resolutions=... does, with one deprecation line per old name."""
  spell = lambda names: [f"--config.{names(k)}={v}" for k, v in OLD_SPELLINGS.items()]
  old, error = _parse(capsys, "--config=fast", *spell(lambda k: k))
  notes = capsys.readouterr().out.strip().splitlines()
  assert error is None
  assert notes == [config_lib.deprecation(k, config_lib.renamed(k)) for k in OLD_SPELLINGS]
  new, error = _parse(capsys, "--config=fast", *spell(config_lib.renamed))
  assert error is None and "deprecated" not in capsys.readouterr().out
  assert old.config.to_dict() == new.config.to_dict()
  assert new.config.model.grid.resolutions == (8, 16)  # the value given, not the default


def test_renamed_fields_in_a_saved_config_or_a_config_file_give_the_new_names_config(tmp_path,
                                                                                     capsys):
  """A config.json of a run from before the rename (flat model.grid_*/hash_* and train.*
  loss fields, render.appearance_protocol; no model.grid, model.hash, loss or eval section)
  restores as the config with the new names; so does a config file setting the old names
  (config_lib.upgrade, one line per old name)."""
  saved = small_config(TWO_STEPS).to_dict()
  del saved["model"]["grid"], saved["model"]["hash"], saved["loss"], saved["eval"]
  for old, value in OLD_SPELLINGS.items():
    section, name = _parent(saved, old)
    section[name] = list(value) if isinstance(value, tuple) else value
  (tmp_path / "config.json").write_text(json.dumps(saved))
  expected = small_config({**TWO_STEPS, **{config_lib.renamed(k): v
                                           for k, v in OLD_SPELLINGS.items()}})
  assert config_lib.load_saved(str(tmp_path)).to_dict() == expected.to_dict()
  # A config file (a ConfigDict accepts new attributes) that sets the old names.
  written = small_config(TWO_STEPS)
  for old, value in OLD_SPELLINGS.items():
    section, name = _parent(written, old)
    section[name] = value
  capsys.readouterr()
  assert config_lib.upgrade(written).to_dict() == expected.to_dict()
  notes = capsys.readouterr().out.strip().splitlines()
  assert notes == [config_lib.deprecation(k, config_lib.renamed(k)) for k in OLD_SPELLINGS]


def _run(args, cwd=ROOT):
  env = dict(os.environ, PYTHONPATH=ROOT)
  return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True,
                        text=True, timeout=300)


def test_render_sets_the_evaluation_overrides_on_the_saved_config(trained):
  exp, _ = experiment.restore(str(trained[0]), overrides={"eval.fit_steps": 300})
  assert exp.config.eval.fit_steps == 300
  saved = config_lib.load_saved(str(trained[0])).eval.fit_steps
  assert saved == evaluation.Settings().fit_steps  # config.json unchanged


@pytest.mark.slow  # three processes
def test_render_takes_evaluation_overrides_only(tmp_path):
  """render.py --config.eval.FIELD=VALUE is parsed and typed against evaluation.Settings; any
  other --config argument is refused in one line (the run's config.json is what it trained)."""
  nowhere = f"--workdir={tmp_path}/nowhere"
  res = _run(["render.py", nowhere, "--mode=eval", "--config.eval.fit_steps=300"])
  assert res.stderr.strip().splitlines() == [f"error: {nowhere}: no such directory"], res.stderr
  res = _run(["render.py", nowhere, "--config.train.lr=1"])
  assert res.returncode == 1 and res.stderr.strip().splitlines() == [
      "error: --config.train.lr: render.py restores the run's config.json; only the evaluation "
      "settings can be overridden (--config.eval.FIELD=VALUE)"], res.stderr
  res = _run(["render.py", nowhere, "--config.eval.fit_steps=many"])
  assert res.returncode == 1 and "--config.eval.fit_steps" in res.stderr, res.stderr


@pytest.mark.slow  # three processes
def test_entry_points_print_one_line(tmp_path):
  res = _run(["train.py", "--config=configs/debug.py", "--config.data.bogus=1",
              f"--workdir={tmp_path}"])
  assert res.returncode == 1 and res.stderr.strip().splitlines() == [
      f"error: --config.data.bogus: config.data has no field 'bogus' (fields: "
      f"{', '.join(sorted(debug.get_config().data.keys()))})"], res.stderr
  res = _run(["render.py", "--workdir=" + str(tmp_path / "nowhere")])
  assert res.returncode == 1 and res.stderr.strip().splitlines() == [
      f"error: --workdir={tmp_path}/nowhere: no such directory"], res.stderr
  res = _run(["train.py", "--config=configs/debug.py",
              f"--config.data.path={tmp_path}/missing.npz", f"--workdir={tmp_path}/w"])
  assert res.returncode == 1, res.stderr
  assert res.stderr.strip().splitlines() == [f"error: {tmp_path}/missing.npz: no such file "
                                             "or directory"], res.stderr


def test_verbosity_asks_for_the_traceback(monkeypatch, tmp_path):
  """With --verbosity the user's error propagates (absl then prints the traceback)."""
  monkeypatch.setattr(flags.FLAGS["verbosity"], "present", 1)
  previous = logging.get_verbosity()
  logging.set_verbosity(logging.DEBUG)
  try:
    with pytest.raises(DataError, match="no such file"):
      cli.run_main(lambda: cli.train(_on(str(tmp_path / "x.npz")), str(tmp_path / "w")))
  finally:
    logging.set_verbosity(previous)


@pytest.mark.parametrize("name", shipped_configs())
def test_every_config_sets_only_fields_the_default_has(name):
  # ConfigDict accepts new attributes, so a misspelt field would silently do nothing.
  flat = lambda c, p="": {k for key, v in c.items()
                          for k in (flat(v, f"{p}{key}.") if hasattr(v, "items")
                                    else [f"{p}{key}"])}
  assert flat(config_lib.load(name)) == flat(default.get_config())
