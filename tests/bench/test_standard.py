"""The standard-benchmark command on tiny fake archives laid out as the real ones unpack:
nerf_synthetic/lego (a built-in scene exported in the Blender format, with opacity) and
nerf_llff_data/fern (a forward-facing scene exported in the LLFF format, with images_8/ cut
here by block averages). Each run trains a few seconds of configs/debug.py.

Checked: the rows' protocol fields (white background and test_every for NeRF-synthetic, the
views every 8th held out for LLFF, the resolution the factor gives), that the runs scored the
views the protocol names (metrics.json's per-view count), the results.md table with the
published figures beside, one clear line for a missing folder or scene, that --dry_run
trains nothing, that each row is stamped (records.py) and says what scoring took, and that the
dry run estimates from the latest measured scoring rate on this backend (records written here)
or says the rate is assumed.
"""

import glob
import json
import os
import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest
from absl import flags

from nerf_jax import cli
from nerf_jax.backend import errors
from nerf_jax.bench import standard
from nerf_jax.data import scenes
from nerf_jax.data.export import export_blender
from nerf_jax.data.llff import export_llff
from tests.bench import test_records
from tests.helpers import ROOT, small_config

BLENDER_VIEWS, BLENDER_TRAIN = 9, 4  # 4 train views, 5 test views (0..4)
LLFF_VIEWS, LLFF_SIZE = 17, 128  # held out: 0, 8, 16; images_8/ of 16 x 16


@pytest.fixture(scope="module")
def archives(tmp_path_factory):
  """{family: archive folder} of a fake nerf_synthetic (lego) and nerf_llff_data (fern)."""
  root = tmp_path_factory.mktemp("archives")
  lego = scenes.make_dataset("diffuse", BLENDER_VIEWS, 16, 16,
                             focal=scenes.TINY_NERF_FOCAL * 16 / 100, pixel_center=0.5)
  export_blender(lego, str(root / "nerf_synthetic" / "lego"), split_at=BLENDER_TRAIN,
                 background=lego.background)  # alpha = opacity, as the real archive
  fern = scenes.make_dataset("forward", LLFF_VIEWS, LLFF_SIZE, LLFF_SIZE,
                             focal=scenes.TINY_NERF_FOCAL * LLFF_SIZE / 100, pixel_center=0.5)
  folder = root / "nerf_llff_data" / "fern"
  export_llff(fern, str(folder))
  small = fern.images.reshape(LLFF_VIEWS, 16, 8, 16, 8, 3).mean((2, 4))  # 8 x 8 blocks
  (folder / "images_8").mkdir()
  for k, image in enumerate(small):
    iio.imwrite(folder / "images_8" / f"{k:03d}.png", np.round(image * 255).astype(np.uint8))
  return {"blender": str(root / "nerf_synthetic"), "llff": str(root / "nerf_llff_data")}


def _command(argv, capsys):
  """Run `python -m nerf_jax.bench.standard` with `argv` (its flags) in this process, on a
  private FlagValues; (rows, printed text)."""
  given = ["nerf_jax.bench.standard", *argv]
  resolved, spec = cli.resolve_config_argv(standard.normalised_argv(given))
  values = flags.FlagValues()
  standard.define_standard_flags(values, resolved)
  errors.parse_flags(resolved, values)
  rows = standard.standard(values, spec, given)
  return rows, capsys.readouterr().out


@pytest.mark.slow  # trains two tiny runs
def test_runs_each_protocol_and_records_it(archives, tmp_path, capsys, monkeypatch):
  out = tmp_path / "out"
  rows, printed = _command(
      [f"--blender={archives['blender']}", f"--llff={archives['llff']}", "--seconds=3",
       "--test-every=2", "--config=configs/debug.py", f"--out={out}"], capsys)
  lines = (out / "results.jsonl").read_text().splitlines()
  assert [json.loads(l) for l in lines] == rows
  lego, fern = rows
  assert (lego["family"], lego["scene"], fern["family"], fern["scene"]) == (
      "blender", "lego", "llff", "fern")

  # NeRF-synthetic: test views 0, 2, 4 of the 5, scored on white, at full resolution.
  assert lego["background"] == "white" and lego["test_every"] == 2
  assert lego["half_res"] is False and lego["resolution"] == [16, 16]
  assert lego["test_views"] == 3
  with open(os.path.join(lego["workdir"], "config.json")) as f:
    saved = json.load(f)
  assert saved["data"]["background"] == "white" and saved["data"]["holdout_from"] == -1
  assert 0 < saved["train"]["max_seconds"] == 3.0
  with open(os.path.join(lego["workdir"], "metrics.json")) as f:
    assert len(json.load(f)["per_view"]) == 3
  with open(os.path.join(archives["blender"], "lego", "transforms_test.json")) as f:
    test_frames = json.load(f)["frames"]
  with open(os.path.join(lego["data"], "transforms_test.json")) as f:
    chosen = json.load(f)["frames"]
  # The subset names the archive's own images (nothing copied): test frames 0, 2 and 4.
  expected = [os.path.join(archives["blender"], "lego", test_frames[k]["file_path"])
              for k in (0, 2, 4)]
  assert [os.path.normpath(f["file_path"]) for f in chosen] == [os.path.normpath(p)
                                                               for p in expected]
  assert not any(n.endswith(".png") for _, _, files in os.walk(out / "views") for n in files)

  # LLFF: factor 8 (16 x 16 from 128 x 128), views 0, 8, 16 held out and scored.
  assert fern["held_out"] == [0, 8, 16] and fern["test_views"] == 3
  assert fern["resolution"] == [16, 16] and "test_every" not in fern
  with open(os.path.join(fern["workdir"], "config.json")) as f:
    assert json.load(f)["data"]["factor"] == 8

  for row in rows:
    assert row["seconds"] > 0 and row["steps"] >= 1
    assert np.isfinite(row["psnr"]) and -1 <= row["ssim"] <= 1  # a few steps: any SSIM
    assert "lpips" in row or row["lpips_missing"]  # 16-pixel images: LPIPS says why not
    assert row["device"] and row["config"] == "debug" and row["date"]
    # The machine its run measured while training (its metrics.json's), with the verdict.
    with open(os.path.join(row["workdir"], "metrics.json")) as f:
      assert row["machine"] == json.load(f)["machine"]
    assert row["machine"]["cpu_count"] >= 1 and isinstance(row["machine"]["busy"], bool)
    assert standard.row_line(row) in printed
  assert "test views 0, 2, 4, ... (3 of 5) on white" in lego["protocol"]
  assert "views 0, 8, 16, ... held out (3 of 17)" in fern["protocol"]
  assert lego["published"] == {"psnr": 32.54, "ssim": 0.961, "lpips": 0.050,
                               "source": standard.NERF_SOURCE}
  assert fern["published"]["psnr"] == 25.17
  table = (out / "results.md").read_text()
  assert "| blender | lego |" in table and "| 32.54 |" in table and "| 25.17 |" in table
  assert "fern" in printed

  # Each row: the stamp, and what scoring took, within its time after training.
  for row, pixels in zip(rows, (3 * 16 * 16, 3 * 16 * 16)):
    test_records.assert_stamped(row, row["machine"])
    assert row["scored_pixels"] == pixels
    assert 0 < row["scoring_seconds"] <= row["wall_seconds"] - row["seconds"] + 0.1  # rounding
    assert standard.row_rate(row) == pytest.approx(pixels / row["scoring_seconds"])
  # A dry run into the same folder estimates each scene at the rate its row measured.
  monkeypatch.setattr(standard, "RECORDS", str(tmp_path / "none" / "*.jsonl"))
  _, printed = _command([f"--blender={archives['blender']}", f"--llff={archives['llff']}",
                         "--seconds=3", "--test-every=2", "--dry_run", f"--out={out}"], capsys)
  for row in rows:
    assert (f"at {standard.row_rate(row):,.0f} pixels/s measured by {row['family']}/"
            f"{row['scene']}, {row['date']}, {out / 'results.jsonl'})") in printed


def test_dry_run_lists_the_runs_and_trains_nothing(archives, tmp_path, capsys):
  # A 360_v2/garden (images_4/) and instant-ngp's fox/transforms.json beside the fixture's two.
  garden = tmp_path / "360_v2" / "garden"
  garden.mkdir(parents=True)
  table = np.load(os.path.join(archives["llff"], "fern", "poses_bounds.npy"))
  np.save(garden / "poses_bounds.npy", table[:10])
  (garden / "images_4").mkdir()
  fox = tmp_path / "fox"
  (fox / "images").mkdir(parents=True)
  frames = []
  for k in range(10):
    iio.imwrite(garden / "images_4" / f"{k:03d}.png", np.zeros((24, 32, 3), np.uint8))
    iio.imwrite(fox / "images" / f"{k:04d}.jpg", np.zeros((27, 48, 3), np.uint8))
    frames.append({"file_path": f"images/{k:04d}.jpg", "transform_matrix": np.eye(4).tolist()})
  (fox / "transforms.json").write_text(json.dumps({"camera_angle_x": 1.0, "frames": frames}))

  out = tmp_path / "out"
  rows, printed = _command([f"--llff={archives['llff']}", f"--blender={archives['blender']}",
                            f"--m360={tmp_path / '360_v2'}", f"--fox={tmp_path}",
                            "--scenes=fern,garden,fox", "--dry_run", f"--out={out}"], capsys)
  assert rows == [] and not out.exists()
  assert "  blender/lego:" not in printed  # not asked for (a rate may come from its row)
  assert "llff/fern: LLFF: factor 8, 16x16, views 0, 8, 16, ... held out (3 of 17)" in printed
  assert ("m360/garden: mip-NeRF 360: factor 4, 32x24, views 0, 8, 16, ... held out (2 of 10)"
          in printed)
  # fox's 48 x 27 photos block-averaged 4x (FOX_FACTOR): 12 x 6 (floor), as the loader's.
  assert ("fox/fox: instant-ngp fox as shipped: factor 4, 12x6, views 0, 8, 16, ... held out "
          "(2 of 10)") in printed
  fox_scene = standard.find_scene("fox", str(tmp_path), "fox")
  assert standard.protocol_config(small_config(base="capture"), fox_scene, fox_scene.path,
                                  7.0, False).data.factor == standard.FOX_FACTOR == 4
  assert "min" in printed
  assert "3 runs of 600 s of training each" in printed  # --seconds' default

  _, printed = _command([f"--llff={archives['llff']}", "--seconds=0", "--dry_run",
                         f"--out={out}"], capsys)  # trained by steps: no time to add
  assert "runs of the config's train.max_steps each (training time not in the estimate)" in printed


@pytest.mark.slow  # the command in a process of its own
@pytest.mark.parametrize("flag, expected", [
    ("--blender={missing}", "{missing}: not found; expected the unpacked nerf_synthetic"),
    ("--llff={llff} --scenes=horns",
     "{llff}/horns/poses_bounds.npy: not found; expected the scene 'horns' of nerf_llff_data"),
    ("--blender={blender} --scenes=fern", "--scenes: 'fern' is no scene of the archives given"),
    ("--llff={llff}/fern", "--llff={llff}/fern is one scene's folder; give the nerf_llff_data "
     "folder that holds it ({llff}) and --scenes=fern"),
    ("--blender={blender} --m360={empty}",
     "{empty}/bicycle: not found; expected a scene folder of 360_v2"),
])
def test_missing_folder_or_scene_is_one_line(archives, tmp_path, flag, expected):
  paths = {"missing": str(tmp_path / "nowhere"), "llff": archives["llff"],
           "blender": archives["blender"], "empty": str(tmp_path / "360_v2")}
  (tmp_path / "360_v2").mkdir()
  result = subprocess.run(
      [sys.executable, "-m", "nerf_jax.bench.standard", *flag.format(**paths).split(),
       f"--out={tmp_path / 'out'}", "--seconds=1"],
      capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": ROOT},
      check=False)
  assert result.returncode == 1
  lines = result.stderr.strip().splitlines()
  assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
  assert expected.format(**paths) in lines[0]
  assert not (tmp_path / "out").exists()


def test_published_figures_agree_with_the_papers_means():
  """The per-scene figures average to NeRF's Table 1 (to its rounding)."""
  for family, means in (("blender", (31.01, 0.947, 0.081)), ("llff", (26.50, 0.811, 0.250))):
    table = np.array([v for (f, _), v in standard.PUBLISHED.items() if f == family])
    assert table.shape == (8, 3)
    # Table 1 rounds to 0.01 dB and 0.001: the means agree to half of that.
    for column, mean, digit in zip(table.T, means, (0.01, 0.001, 0.001)):
      np.testing.assert_allclose(column.mean(), mean, atol=0.5 * digit + 1e-9)


def test_protocol_config_sets_the_protocol_and_auto_keeps_it():
  base = small_config({"data.background": "black", "data.holdout_from": 10})
  scene = standard.Scene("blender", "lego", "/data/nerf_synthetic/lego", 400, 400, 200, [0])
  config = standard.protocol_config(base, scene, "/data/view", 7.0, True, ("train.batch_rays",))
  assert (config.data.path, config.data.background, config.data.half_res) == (
      "/data/view", "white", True)
  assert config.data.holdout_from == -1 and config.train.max_seconds == 7.0
  assert {"train.batch_rays", "data.background", "data.half_res", "data.path",
          "train.max_seconds"} <= set(config.auto_flags)
  assert base.data.background == "black" and base.data.path == ""  # the base is untouched
  fern = standard.Scene("llff", "fern", "/data/nerf_llff_data/fern", 378, 504, 20, [0, 8, 16])
  assert standard.protocol_config(base, fern, fern.path, 7.0, False).data.factor == 8


def test_a_run_with_appearance_codes_says_how_its_views_were_scored():
  saved = {"model": {"appearance_dims": 8}, "eval": {"appearance": "left_half"},
           "auto_decisions": ["an object on a background"]}
  choices = standard.run_choices(saved)
  assert choices == {"background": None, "appearance_codes": {"dims": 8, "held_out": "left_half"},
                     "auto_decisions": ["an object on a background"]}
  assert standard.run_choices({"data": {"background": "white"}, "model": {"appearance_dims": 0},
                              "eval": {}}) == {"background": "white"}
  scene = standard.Scene("llff", "fern", "/data/fern", 378, 504, 20, [0, 8, 16])
  metrics = {"psnr": 20.0, "ssim": 0.5, "steps": 10, "train_seconds": 3.0,
             "lpips_skipped": "no weights", "per_view": [{}, {}, {}]}
  row = standard.make_row(scene, metrics, {**choices, "protocol": standard.protocol(scene)})
  assert row["protocol"].endswith("held-out views scored with eval.appearance=left_half")
  assert row["lpips_missing"] == "no weights" and "lpips" not in row
  assert row["held_out"] == [0, 8, 16] and row["test_views"] == 3


def test_a_row_whose_machine_was_busy_says_so_in_its_line_and_the_table():
  scene = standard.Scene("llff", "fern", "/data/fern", 378, 504, 20, [0, 8, 16])
  metrics = {"psnr": 20.0, "ssim": 0.5, "steps": 10, "train_seconds": 3.0, "lpips": 0.3}
  extra = {"protocol": standard.protocol(scene), "device": "cpu: cpu (x1)", "config": "auto",
           "date": "today"}
  busy = {"busy": True, "busy_why": "load 3.1 on 2 CPUs"}
  row = standard.make_row(scene, metrics, {**extra, "machine": busy})
  assert row["machine"] == busy
  assert standard.row_line(row) == ("llff/fern: PSNR 20.00, SSIM 0.500 after 10 steps in 3 s "
                                    "(busy: load 3.1 on 2 CPUs)")
  assert "| cpu: cpu (x1) (busy: load 3.1 on 2 CPUs) | auto |" in standard.markdown([row], "c")
  idle = standard.make_row(scene, metrics, {**extra, "machine": {"busy": False}})
  assert standard.row_line(idle).endswith("in 3 s") and "busy" not in standard.markdown(
      [idle], "c")


def _row(family, scene, date, backend="cpu", **fields):
  """A standard row as written on `backend`: stamped, with what scoring took."""
  return {"family": family, "scene": scene, "date": date, "device": f"{backend}: x (x1)",
          "machine": {"backend": backend}, "test_views": 2, "resolution": [10, 10],
          "wall_seconds": 100.0, "seconds": 60.0, **fields}


def test_a_rows_scoring_rate_is_measured_or_derived_from_its_times():
  new = _row("blender", "lego", "d", scored_pixels=4000, scoring_seconds=0.5)
  assert standard.row_rate(new) == 8000.0
  # An older row: test views x resolution over the time after training less the set-up.
  old = {"family": "llff", "scene": "fern", "test_views": 3, "resolution": [378, 504],
         "wall_seconds": 648.5, "seconds": 609.868, "device": "cpu: cpu (x1)",
         "machine": "2-core AMD EPYC VM, no GPU, nothing else running"}
  after = 648.5 - 609.868 - standard.SETUP_SECONDS
  assert standard.row_rate(old) == pytest.approx(3 * 378 * 504 / after)
  assert standard.row_backend(old) == "cpu" and standard.row_backend(new) == "cpu"
  assert standard.row_rate({**old, "wall_seconds": 620.0}) is None  # no time left to score
  assert standard.row_rate({"family": "llff", "scene": "fern"}) is None


def _committed_rows(name):
  with open(os.path.join(ROOT, "docs", "bench", "standard", name)) as f:
    return [json.loads(line) for line in f if line.strip()]


def test_the_committed_lego_rows_score_at_their_measured_rates():
  # The row of 2026-11-28 predates scoring_seconds: 25 views of 400 x 400 in about 144 s.
  (before,) = [r for r in _committed_rows("cpu_2026-11-28.jsonl") if r["scene"] == "lego"]
  assert 27_000 < standard.row_rate(before) < 29_000
  # The dry run takes the latest lego row on this backend, which records its scoring.
  latest = max((r for r in _committed_rows("cpu_2026-11-29.jsonl") if r["scene"] == "lego"),
               key=lambda r: r["date"])
  lego = standard.measured_rates(glob.glob(standard.RECORDS), "cpu")[("blender", "lego")]
  assert lego.pixels_per_second == pytest.approx(
      latest["scored_pixels"] / latest["scoring_seconds"])
  assert lego.source.startswith(f"blender/lego, {latest['date']}, docs/bench/standard/")
  assert standard.measured_rates(glob.glob(standard.RECORDS), "tpu") == {}


def test_the_dry_run_scores_at_the_latest_rate_on_this_backend(archives, tmp_path, capsys,
                                                               monkeypatch):
  committed = tmp_path / "standard" / "cpu_then.jsonl"
  committed.parent.mkdir()
  rows = [_row("llff", "fern", "2026-01-01 00:00 UTC", scored_pixels=1000, scoring_seconds=1.0),
          _row("llff", "fern", "2026-02-01 00:00 UTC", scored_pixels=3000, scoring_seconds=1.0),
          _row("llff", "fern", "2026-03-01 00:00 UTC", "gpu", scored_pixels=9e6,
               scoring_seconds=1.0),  # another backend
          _row("fox", "fox", "2026-01-01 00:00 UTC", scored_pixels=500, scoring_seconds=1.0)]
  committed.write_text("".join(json.dumps(r) + "\n" for r in rows))
  out = tmp_path / "out"
  out.mkdir()  # a later run of fox in the --out folder
  (out / "results.jsonl").write_text(json.dumps(
      _row("fox", "fox", "2026-04-01 00:00 UTC", scored_pixels=2000, scoring_seconds=1.0)))
  monkeypatch.setattr(standard, "RECORDS", str(tmp_path / "standard" / "*.jsonl"))
  rates = standard.measured_rates(standard.record_paths(str(out)), "cpu")
  assert {k: r.pixels_per_second for k, r in rates.items()} == {
      ("llff", "fern"): 3000.0, ("fox", "fox"): 2000.0}
  fern = standard.find_scene("llff", archives["llff"], "fern")
  lego = standard.find_scene("blender", archives["blender"], "lego")
  assert standard.scoring_rate(fern, rates) is rates[("llff", "fern")]
  assert standard.scoring_rate(lego, rates) is rates[("fox", "fox")]  # the slowest measured
  assert standard.estimated_seconds(fern, 60.0, rates[("llff", "fern")]) == pytest.approx(
      60.0 + standard.SETUP_SECONDS + 3 * 16 * 16 / 3000.0)

  _, printed = _command([f"--blender={archives['blender']}", f"--llff={archives['llff']}",
                         "--dry_run", f"--out={out}"], capsys)
  assert (f"(scoring 768 pixels at 3,000 pixels/s measured by llff/fern, 2026-02-01 00:00 UTC, "
          f"{committed})") in printed
  assert (f"(scoring 1,280 pixels at 2,000 pixels/s measured by fox/fox, 2026-04-01 00:00 UTC, "
          f"{out / 'results.jsonl'})") in printed  # lego: 5 test views of 16 x 16
  # No record on this backend: the rate is assumed, and says so.
  monkeypatch.setattr(standard, "RECORDS", str(tmp_path / "nowhere" / "*.jsonl"))
  _, printed = _command([f"--llff={archives['llff']}", "--dry_run",
                         f"--out={tmp_path / 'empty'}"], capsys)
  assert ("at 200,000 pixels/s assumed (no record on this backend))" in printed
          and "measured" not in printed)
