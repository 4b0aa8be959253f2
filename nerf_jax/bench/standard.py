"""The standard benchmarks, on their archives as a researcher unpacks them: one command.

  python -m nerf_jax.bench.standard --blender=data/nerf_synthetic --llff=data/nerf_llff_data \
      --m360=data/360_v2 --fox=data/fox --seconds=600 --out=runs/standard

Each family is scored by the protocol its paper uses (`PROTOCOLS`):
  blender  nerf_synthetic/<scene>/transforms_{train,test}.json: trained on the train split,
           scored on the test split composited on white; full 800 px, or 400 px with
           --blender_half; --test_every=N scores test views 0, N, 2N, ... only (a folder of
           two small JSON files under OUT/views/ that name the archive's own images).
  llff     nerf_llff_data/<scene>/poses_bounds.npy + images_8/: factor 8, views 0, 8, 16, ...
           held out (the loader's rule for poses_bounds.npy, `Dataset.split_every`).
  m360     360_v2/<scene>/poses_bounds.npy + images_4/: factor 4, every 8th view held out.
  fox      instant-ngp's fox/transforms.json as shipped, its photos block-averaged 4x on loading
           (FOX_FACTOR): every 8th frame (sorted by file path) held out, the loader's rule for a
           transforms.json that names no test images.

Each run is `train_lib.train_and_evaluate` of the --config (default configs/auto.py, with any
--config.FIELD=VALUE overrides) in OUT/<family>_<scene>, stopped by the clock
(train.max_seconds = --seconds); its metrics.json gives the scores. Rows go to
OUT/results.jsonl as the runs finish (stamped: records.py; with what scoring took,
scoring_seconds for scored_pixels), and OUT/results.md is rewritten after each, beside the
published figures of `PUBLISHED`. A missing folder or scene stops the command before anything
trains, with one line naming the path and what belongs there; --dry_run checks the folders and
lists the runs with their estimated time, scoring at the rate the latest standard record on
this backend measured (`scoring_rate`: the scene's own, else the slowest), or at an assumed
one where none did.
"""

import dataclasses
import glob
import json
import os
import shlex
import sys
import time

import imageio.v3 as iio
import jax
import numpy as np
from absl import flags

from nerf_jax import cli
from nerf_jax.bench import child, command_line, records
from nerf_jax.run import machine, train_lib

FAMILIES = ("blender", "llff", "m360", "fox")
# The scenes of each archive, in the papers' order.
SCENES = {
    "blender": ("chair", "drums", "ficus", "hotdog", "lego", "materials", "mic", "ship"),
    "llff": ("fern", "flower", "fortress", "horns", "leaves", "orchids", "room", "trex"),
    "m360": ("bicycle", "bonsai", "counter", "flowers", "garden", "kitchen", "room", "stump",
             "treehill"),
    "fox": ("fox",),
}
ARCHIVES = {"blender": "nerf_synthetic", "llff": "nerf_llff_data", "m360": "360_v2",
            "fox": "fox"}  # the folder each archive unpacks to
FACTORS = {"llff": 8, "m360": 4}  # images_<factor>/ of the papers' resolution
# fox: its 1920 x 1080 photos block-averaged 4x on loading (960 x 540 would take 37 minutes to
# score on 2 cores at training's rate; the project's fox figures are at factor 4,
# docs/real_captures.md).
FOX_FACTOR = 4
HOLD_OUT_EVERY = 8  # llff, m360, fox: views 0, 8, 16, ... are the test views

# NeRF (Mildenhall et al., ECCV 2020), the per-scene breakdown in the appendix (arXiv:2003.08934):
# (PSNR, SSIM, LPIPS) of NeRF on the realistic synthetic scenes (800 px, white) and the real
# forward-facing scenes (LLFF at factor 8, every 8th image held out). Their means are the
# paper's Table 1 (31.01 / 0.947 / 0.081 and 26.50 / 0.811 / 0.250).
NERF_SOURCE = "NeRF (Mildenhall et al. 2020), appendix per-scene tables"
PUBLISHED = {
    ("blender", "chair"): (33.00, 0.967, 0.046),
    ("blender", "drums"): (25.01, 0.925, 0.091),
    ("blender", "ficus"): (30.13, 0.964, 0.044),
    ("blender", "hotdog"): (36.18, 0.974, 0.121),
    ("blender", "lego"): (32.54, 0.961, 0.050),
    ("blender", "materials"): (29.62, 0.949, 0.063),
    ("blender", "mic"): (32.91, 0.980, 0.028),
    ("blender", "ship"): (28.65, 0.856, 0.206),
    ("llff", "fern"): (25.17, 0.792, 0.280),
    ("llff", "flower"): (27.40, 0.827, 0.219),
    ("llff", "fortress"): (31.16, 0.881, 0.171),
    ("llff", "horns"): (27.45, 0.828, 0.268),
    ("llff", "leaves"): (20.92, 0.690, 0.316),
    ("llff", "orchids"): (20.36, 0.641, 0.321),
    ("llff", "room"): (32.70, 0.948, 0.178),
    ("llff", "trex"): (26.80, 0.880, 0.249),
}

# The dry run's estimate of a run's time besides training: set-up (load, compile) and scoring
# the test views at the rate the latest standard record on this backend measured (RECORDS and
# the --out folder's results.jsonl: `scoring_rate`); without one, at an assumed rate.
EVAL_PIXELS_PER_SECOND = 200_000  # assumed where no record on this backend measured one
SETUP_SECONDS = 30  # assumed; also taken off an older row's time after training (`row_rate`)
# The committed standard records (docs/bench/standard/<backend>_<date>.jsonl).
RECORDS = os.path.join(child.ROOT, "docs", "bench", "standard", "*.jsonl")


@dataclasses.dataclass
class Scene:
  """One benchmark run's data, as found on disk.

  family, name: e.g. 'blender', 'lego'. path: the scene's folder (the archive's own). height,
  width: the test images' pixels as the run sees them (after the factor or half resolution).
  views: the views in the archive (blender: the test split's). test_views: int list, the
  indices of the scored views (blender: in the test split; otherwise among all the views, in
  the loader's order).
  """
  family: str
  name: str
  path: str
  height: int
  width: int
  views: int
  test_views: list


def _missing(path, expected):
  return FileNotFoundError(f"{path}: not found; expected {expected}")


def _image_size(path):
  """(height, width) of the image file `path`."""
  return tuple(iio.improps(path).shape[:2])


def _images_in(folder):
  return sorted(n for n in os.listdir(folder) if n.lower().endswith((".png", ".jpg", ".jpeg")))


def _blender_frame_image(folder, frame):
  path = os.path.join(folder, frame["file_path"])
  return path if os.path.isfile(path) else path + ".png"


def _find_blender(root, name, half, test_every):
  folder = os.path.join(root, name)
  meta_path = os.path.join(folder, "transforms_test.json")
  for split in ("train", "test"):
    if not os.path.isfile(os.path.join(folder, f"transforms_{split}.json")):
      raise _missing(os.path.join(folder, f"transforms_{split}.json"),
                     f"the NeRF-synthetic scene {name!r} (nerf_synthetic/{name}/ with "
                     "transforms_train.json, transforms_test.json and their PNGs)")
  with open(meta_path) as f:
    frames = json.load(f).get("frames") or []
  if not frames:
    raise ValueError(f"{meta_path}: no frames")
  image = _blender_frame_image(folder, frames[0])
  if not os.path.isfile(image):
    raise _missing(image, f"the test images that {meta_path} names")
  height, width = _image_size(image)
  if half:
    height, width = height // 2, width // 2
  return Scene("blender", name, folder, height, width, len(frames),
               list(range(0, len(frames), test_every)))


def _find_poses_bounds(family, root, name):
  folder, factor = os.path.join(root, name), FACTORS[family]
  archive = "nerf_llff_data" if family == "llff" else "360_v2"
  table_path = os.path.join(folder, "poses_bounds.npy")
  images = os.path.join(folder, f"images_{factor}")
  if not os.path.isfile(table_path):
    raise _missing(table_path, f"the scene {name!r} of {archive} ({archive}/{name}/ with "
                   f"poses_bounds.npy and images_{factor}/)")
  if not os.path.isdir(images) or not _images_in(images):
    raise _missing(images, f"the images of {name!r} downsampled {factor}x, as {archive} "
                   "ships them")
  views = len(np.load(table_path))
  height, width = _image_size(os.path.join(images, _images_in(images)[0]))
  return Scene(family, name, folder, height, width, views,
               list(range(0, views, HOLD_OUT_EVERY)))


def _find_fox(root):
  folder = root if os.path.isfile(os.path.join(root, "transforms.json")) else os.path.join(
      root, "fox")
  meta_path = os.path.join(folder, "transforms.json")
  if not os.path.isfile(meta_path):
    raise _missing(os.path.join(root, "transforms.json"), "instant-ngp's fox scene (fox/ with "
                   "transforms.json and images/)")
  with open(meta_path) as f:
    frames = json.load(f).get("frames") or []
  if not frames:
    raise ValueError(f"{meta_path}: no frames")
  image = os.path.join(folder, sorted(f["file_path"] for f in frames)[0])
  if not os.path.isfile(image):
    raise _missing(image, f"the images that {meta_path} names")
  height, width = _image_size(image)
  height, width = height // FOX_FACTOR, width // FOX_FACTOR
  return Scene("fox", "fox", folder, height, width, len(frames),
               list(range(0, len(frames), HOLD_OUT_EVERY)))


def find_scene(family, root, name, half=False, test_every=1):
  """The Scene `name` of `family` under the archive folder `root`; FileNotFoundError with one
  line naming the path and what belongs there."""
  _check_archive(family, root)
  if family == "blender":
    return _find_blender(root, name, half, test_every)
  if family == "fox":
    return _find_fox(root)
  return _find_poses_bounds(family, root, name)


def _check_archive(family, root):
  """FileNotFoundError with one line unless `root` is an archive folder of `family` (not, say,
  one scene's folder of it)."""
  if not os.path.isdir(root):
    raise _missing(root, f"the unpacked {ARCHIVES[family]} folder (--{family})")
  if family != "fox" and any(os.path.isfile(os.path.join(root, f)) for f in (
      "transforms_train.json", "poses_bounds.npy")):
    raise FileNotFoundError(
        f"--{family}={root} is one scene's folder; give the {ARCHIVES[family]} folder that "
        f"holds it ({os.path.dirname(os.path.abspath(root))}) and --scenes="
        f"{os.path.basename(os.path.abspath(root))}")


def plan(roots, names=(), half=False, test_every=1):
  """The Scenes to run. roots: {family: archive folder} (those given). names: the scenes asked
  for (default: every scene of SCENES whose folder is in the archive folders given). Raises
  FileNotFoundError or ValueError with one line when a folder, a scene or a file of one is
  missing."""
  if not roots:
    raise ValueError("no archive given: pass at least one of --blender, --llff, --m360, --fox")
  if test_every < 1:
    raise ValueError(f"--test_every={test_every}: must be >= 1")
  for family, root in roots.items():
    _check_archive(family, root)
  wanted = []
  if names:
    for name in names:
      families = [f for f in roots if name in SCENES[f]]
      if not families:
        known = ", ".join(f"--{f}: {', '.join(SCENES[f])}" for f in roots)
        raise ValueError(f"--scenes: {name!r} is no scene of the archives given ({known})")
      wanted += [(f, name) for f in families]
  else:
    for family, root in roots.items():
      found = [n for n in SCENES[family]
               if family == "fox" or os.path.isdir(os.path.join(root, n))]
      if not found:
        raise _missing(os.path.join(root, SCENES[family][0]), f"a scene folder of "
                       f"{ARCHIVES[family]} ({', '.join(SCENES[family])})")
      wanted += [(family, n) for n in found]
  return [find_scene(f, roots[f], n, half, test_every) for f, n in wanted]


def protocol(scene, half=False, test_every=1):
  """The row's protocol fields of `scene`: {'protocol' (one line), 'resolution', and
  'background', 'half_res', 'test_every' (blender) or 'held_out' (the others: held-out view
  indices)}."""
  size = f"{scene.width}x{scene.height}"
  if scene.family == "blender":
    views = (f"test views 0, {test_every}, {2 * test_every}, ... ({len(scene.test_views)} of "
             f"{scene.views})" if test_every > 1 else f"all {scene.views} test views")
    text = (f"NeRF-synthetic: trained on train, scored on {views} on white, "
            f"{size}{' (half resolution)' if half else ''}")
    return {"protocol": text, "background": "white", "resolution": [scene.height, scene.width],
            "half_res": half, "test_every": test_every}
  factor = f"factor {_factor(scene.family)}, "
  what = {"llff": "LLFF", "m360": "mip-NeRF 360", "fox": "instant-ngp fox as shipped"}
  text = (f"{what[scene.family]}: {factor}{size}, views 0, {HOLD_OUT_EVERY}, "
          f"{2 * HOLD_OUT_EVERY}, ... held out ({len(scene.test_views)} of {scene.views})")
  return {"protocol": text, "resolution": [scene.height, scene.width],
          "held_out": scene.test_views}


def _factor(family):
  """The factor the photos of `family` (not 'blender') are scored at."""
  return FOX_FACTOR if family == "fox" else FACTORS[family]


@dataclasses.dataclass
class Rate:
  """A scoring rate and where it came from. pixels_per_second: float > 0. source: the row it
  was measured by ('blender/lego, 2026-11-28 05:34 UTC, docs/bench/standard/cpu_...jsonl'),
  or None for the assumed EVAL_PIXELS_PER_SECOND."""
  pixels_per_second: float
  source: object = None


ASSUMED = Rate(EVAL_PIXELS_PER_SECOND)


def row_backend(row):
  """The JAX backend a standard row ran on: its machine record's, else (older rows, whose
  'machine' is a line of text) the platform its 'device' names ('cpu: cpu (x1)')."""
  machine_record = row.get("machine")
  if isinstance(machine_record, dict) and machine_record.get("backend"):
    return machine_record["backend"]
  return str(row.get("device", "")).split(":")[0] or None


def row_rate(row):
  """The pixels a second a standard row's scoring took: its scored_pixels over its
  scoring_seconds; an older row's from its test views x resolution over its time after
  training (wall_seconds - seconds) less SETUP_SECONDS. None where neither gives a time > 0."""
  if (row.get("scoring_seconds") or 0) > 0 and row.get("scored_pixels"):
    return row["scored_pixels"] / row["scoring_seconds"]
  try:
    pixels = row["test_views"] * row["resolution"][0] * row["resolution"][1]
    after = row["wall_seconds"] - row["seconds"] - SETUP_SECONDS
  except (KeyError, TypeError, IndexError):
    return None
  return pixels / after if after > 0 and pixels > 0 else None


def _shown(path):
  """`path` as the checkout's relative path where it lies in it (docs/bench/...)."""
  inside = os.path.relpath(os.path.abspath(path), child.ROOT)
  return path if inside.startswith(os.pardir) else inside


def measured_rates(paths, backend):
  """{(family, scene): Rate} of the latest row (by date, then by place) of each scene in the
  standard records `paths` (JSON-lines files; absent ones skipped) that ran on `backend` and
  gives a rate (`row_rate`)."""
  latest = {}
  for path in paths:
    for row in records.read(path):
      rate = row_rate(row)
      if rate is None or row_backend(row) != backend or "family" not in row:
        continue
      key, date = (row["family"], row.get("scene")), str(row.get("date", ""))
      if key not in latest or date >= latest[key][0]:
        source = f"{key[0]}/{key[1]}, {date or 'undated'}, {_shown(path)}"
        latest[key] = (date, Rate(rate, source))
  return {key: rate for key, (_, rate) in latest.items()}


def record_paths(out):
  """The standard records the dry run reads: RECORDS, then OUT/results.jsonl."""
  return sorted(glob.glob(RECORDS)) + [os.path.join(out, "results.jsonl")]


def scoring_rate(scene, rates):
  """The Rate `scene` is estimated at: its own in `rates` (`measured_rates`), else the slowest
  measured, else ASSUMED."""
  own = rates.get((scene.family, scene.name))
  return own or min(rates.values(), key=lambda r: r.pixels_per_second, default=ASSUMED)


def scored_pixels(scene):
  """The pixels scoring `scene` renders: its test views x height x width."""
  return len(scene.test_views) * scene.height * scene.width


def estimated_seconds(scene, seconds, rate=ASSUMED):
  """A rough wall time of one run: the budget, SETUP_SECONDS and scoring its test views at
  `rate` (a Rate)."""
  return seconds + SETUP_SECONDS + scored_pixels(scene) / rate.pixels_per_second


def rate_words(rate):
  """'27,800 pixels/s measured by SOURCE', or '200,000 pixels/s assumed' for ASSUMED."""
  said = f"measured by {rate.source}" if rate.source else "assumed (no record on this backend)"
  return f"{rate.pixels_per_second:,.0f} pixels/s {said}"


def blender_view_folder(scene, folder, test_every):
  """A NeRF-synthetic folder at `folder` that scores every `test_every`th test view of
  `scene`: transforms_train.json and transforms_test.json (test frames 0, N, 2N, ...) whose
  file paths name the archive's own images (absolute paths), nothing copied. Returns folder."""
  os.makedirs(folder, exist_ok=True)
  for split in ("train", "test"):
    with open(os.path.join(scene.path, f"transforms_{split}.json")) as f:
      meta = json.load(f)
    frames = meta["frames"][::test_every] if split == "test" else meta["frames"]
    for frame in frames:
      for key in ("file_path", "mask_path"):
        if frame.get(key):
          frame[key] = os.path.abspath(os.path.join(scene.path, frame[key]))
    meta["frames"] = frames
    with open(os.path.join(folder, f"transforms_{split}.json"), "w") as f:
      json.dump(meta, f, indent=1)
  return folder


def protocol_config(base, scene, data_path, seconds, half, overrides=()):
  """A copy of the ConfigDict `base` that trains `scene` by its protocol from `data_path` for
  `seconds` (command_line.command_config: the fields set here and `overrides`, the dotted
  fields the command line set, go into config.auto_flags, so that auto keeps them)."""
  fields = {"data.path": data_path, "data.holdout_from": -1, "train.max_seconds": float(seconds),
            "render.after_training": False}
  if scene.family == "blender":
    fields.update({"data.background": "white", "data.half_res": bool(half)})
  else:
    fields["data.factor"] = _factor(scene.family)
  return command_line.command_config(base, fields, overrides)[0]


def device():
  """The accelerator the runs use, in words: 'gpu: NVIDIA H100 80GB HBM3 (x1)'."""
  devices = jax.devices()
  return f"{devices[0].platform}: {devices[0].device_kind} (x{len(devices)})"


def run_choices(saved):
  """What a run's config.json (`saved`, a dict) says about how it was scored: {'background':
  data.background, the colour it was scored on}, with 'appearance_codes': {'dims', 'held_out'}
  where it learnt per-photo codes (its held-out views then scored by eval.appearance:
  'left_half' is NeRF-W's fit, not the papers' protocol), and 'auto_decisions' (auto's lines)
  where auto chose the config."""
  choices = {"background": saved.get("data", {}).get("background")}
  dims = saved.get("model", {}).get("appearance_dims", 0)
  if dims:
    choices["appearance_codes"] = {"dims": dims,
                                   "held_out": saved.get("eval", {}).get("appearance")}
  if saved.get("auto_decisions"):
    choices["auto_decisions"] = list(saved["auto_decisions"])
  return choices


def make_row(scene, metrics, extra):
  """One results.jsonl row: the scene, its protocol, the scores of metrics.json (LPIPS, or
  'lpips_missing' saying why) and `extra` (seconds, device, config, date, `run_choices`...);
  a run with appearance codes says so in its protocol line."""
  fields = {**extra["protocol"], **({"background": extra["background"]}
                                    if "background" in extra else {})}
  codes = extra.get("appearance_codes")
  if codes:
    fields["protocol"] += (f"; per-photo appearance codes, held-out views scored with "
                           f"eval.appearance={codes['held_out']}")
  row = {"family": scene.family, "scene": scene.name, **fields,
         "test_views": len(metrics.get("per_view", [])) or len(scene.test_views),
         "psnr": metrics["psnr"], "ssim": metrics["ssim"]}
  if "lpips" in metrics:
    row["lpips"] = metrics["lpips"]
  else:
    row["lpips_missing"] = metrics.get("lpips_skipped", "not computed")
  row.update(steps=metrics["steps"], seconds=metrics["train_seconds"],
             **{k: v for k, v in extra.items() if k not in ("protocol", "background")})
  published = PUBLISHED.get((scene.family, scene.name))
  if published:
    row["published"] = dict(zip(("psnr", "ssim", "lpips"), published), source=NERF_SOURCE)
  return row


def _cell(value, decimals):
  return "-" if value is None else f"{value:.{decimals}f}"


def row_line(row):
  """One line of a finished run: its scores, steps and seconds, and whether the machine was
  busy while it trained (the row's 'machine', run/machine.py)."""
  return (f"{row['family']}/{row['scene']}: PSNR {row['psnr']:.2f}, SSIM {row['ssim']:.3f} "
          f"after {row['steps']} steps in {row['seconds']:.0f} s"
          f"{machine.busy_note(row.get('machine'))}")


def markdown(rows, command):
  """results.md: the command, then one table row per run with the published figures beside."""
  lines = ["# Standard benchmarks", "", "```", command, "```", "",
           "| family | scene | protocol | PSNR | SSIM | LPIPS | steps | seconds | published "
           "PSNR | SSIM | LPIPS | device | config | date |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for row in rows:
    pub = row.get("published", {})
    lines.append(
        f"| {row['family']} | {row['scene']} | {row['protocol']} | {row['psnr']:.2f} | "
        f"{row['ssim']:.3f} | {_cell(row.get('lpips'), 3)} | {row['steps']} | "
        f"{row['seconds']:.0f} | {_cell(pub.get('psnr'), 2)} | {_cell(pub.get('ssim'), 3)} | "
        f"{_cell(pub.get('lpips'), 3)} | {row['device']}{machine.busy_note(row.get('machine'))} | "
        f"{row['config']} | {row['date']} |")
  missing = sorted({r["lpips_missing"] for r in rows if "lpips_missing" in r})
  if missing:
    lines += ["", "LPIPS missing: " + "; ".join(missing) + "."]
  if any("published" in r for r in rows):
    lines += ["", f"Published: {NERF_SOURCE} (PSNR, SSIM, LPIPS of NeRF)."]
  return "\n".join(lines) + "\n"


class TrainingEnd:
  """A watcher of train_lib.train_and_evaluate that notes when the last step ended (`at`,
  time.perf_counter()): what follows, until the call returns, is scoring the test views."""

  def __init__(self):
    self.at = None

  def after_step(self, step, variables_fn):
    del step, variables_fn  # every step: nothing to do

  def close(self):
    self.at = time.perf_counter()


def run_benchmark(base, config_name, scenes, out, seconds, half, test_every, command,
                  overrides=()):
  """Train and score each of `scenes` (Scenes of `plan`) in OUT/<family>_<scene> with the
  ConfigDict `base` (named `config_name` in the rows; `overrides`: the fields the command line
  set on it) for `seconds` each; writes OUT/results.jsonl and OUT/results.md after each run.
  Returns the rows."""
  os.makedirs(out, exist_ok=True)
  results = os.path.join(out, "results.jsonl")
  records.write(results, [])
  rows, where = [], device()
  for scene in scenes:
    workdir = os.path.join(out, f"{scene.family}_{scene.name}")
    data_path = scene.path
    if scene.family == "blender" and test_every > 1:
      data_path = blender_view_folder(scene, os.path.join(out, "views", scene.name), test_every)
    print(f"{scene.family}/{scene.name}: training {seconds:g} s into {workdir}", flush=True)
    start, trained = time.perf_counter(), TrainingEnd()
    train_lib.train_and_evaluate(
        protocol_config(base, scene, data_path, seconds, half, overrides), workdir,
        watchers=(lambda *_: trained,))
    end = time.perf_counter()
    with open(os.path.join(workdir, "metrics.json")) as f:
      metrics = json.load(f)
    with open(os.path.join(workdir, "config.json")) as f:
      choices = run_choices(json.load(f))
    row = make_row(scene, metrics, {**choices,
        "protocol": protocol(scene, half, test_every), "data": data_path,
        "wall_seconds": round(end - start, 1), "device": where, "config": config_name,
        "workdir": workdir})
    if trained.at is not None:  # the loop closes its watchers once, after the last step
      row.update(scoring_seconds=round(end - trained.at, 2),
                 scored_pixels=row["test_views"] * scene.height * scene.width)
    rows.append(records.stamp(row, metrics.get("machine")))  # measured while it trained
    print(row_line(rows[-1]), flush=True)
    records.append(results, rows[-1])
    with open(os.path.join(out, "results.md"), "w") as f:
      f.write(markdown(rows, command))
  print(f"-> {results}, {os.path.join(out, 'results.md')}", flush=True)
  return rows


# ------------------------------------------------------- python -m nerf_jax.bench.standard


def define_standard_flags(values, argv):
  """The flags of `python -m nerf_jax.bench.standard` on the FlagValues `values`. argv: the
  command line after cli.resolve_config_argv (see `normalised_argv`)."""
  command_line.define_config(values, argv, "Config of every run (default auto: decided from "
                             "each scene's data); --config.FIELD=VALUE overrides apply to "
                             "every run.")
  for family in FAMILIES:
    flags.DEFINE_string(family, "", f"The unpacked {ARCHIVES[family]} folder.",
                        flag_values=values)
  flags.DEFINE_float("seconds", 600.0, "Wall-clock training budget per scene "
                     "(train.max_seconds; 0 = the config's steps).", flag_values=values,
                     lower_bound=0.0)
  flags.DEFINE_list("scenes", [], "Scenes to run (default: every standard scene found in "
                    "the folders given).", flag_values=values)
  flags.DEFINE_integer("test_every", 1, "NeRF-synthetic: score test views 0, N, 2N, ... "
                       "(recorded).", flag_values=values, lower_bound=1)
  flags.DEFINE_bool("blender_half", False, "NeRF-synthetic at half resolution (400 px).",
                    flag_values=values)
  flags.DEFINE_string("out", "runs/standard", "Output folder: results.jsonl, results.md and "
                      "one workdir per scene.", flag_values=values)
  flags.DEFINE_bool("dry_run", False, "Check the folders and list the runs; train nothing.",
                    flag_values=values)


def standard(values, spec, argv):
  """Run (or, with --dry_run, list) what the parsed flags ask for; returns the rows ([] for a
  dry run)."""
  roots = {f: values[f].value for f in FAMILIES if values[f].value}
  scenes = plan(roots, values.scenes, values.blender_half, values.test_every)
  rates = measured_rates(record_paths(values.out), jax.default_backend())
  total = 0.0
  budget = (f"{values.seconds:g} s of training each" if values.seconds > 0 else
            "the config's train.max_steps each (training time not in the estimate)")
  print(f"{len(scenes)} runs of {budget}, into {values.out}:")
  for scene in scenes:
    rate = scoring_rate(scene, rates)
    estimate = estimated_seconds(scene, values.seconds, rate)
    total += estimate
    line = protocol(scene, values.blender_half, values.test_every)["protocol"]
    print(f"  {scene.family}/{scene.name}: {line}; about {estimate / 60:.0f} min (scoring "
          f"{scored_pixels(scene):,} pixels at {rate_words(rate)})", flush=True)
  print(f"about {total / 60:.0f} min in all, {SETUP_SECONDS} s of set-up each assumed",
        flush=True)
  if values.dry_run:
    return []
  name = os.path.splitext(os.path.basename(spec.split(":")[0]))[0] or "auto"
  command = "python -m nerf_jax.bench.standard " + shlex.join(argv[1:])
  return run_benchmark(values["config"].value, name, scenes, values.out, values.seconds,
                       values.blender_half, values.test_every, command, cli.override_names(argv))


HYPHENATED = ("--test-every", "--blender-half", "--noblender-half", "--dry-run", "--nodry-run")


def normalised_argv(argv):
  """argv with --config=auto added when it names no config (this command's default), and the
  flags spelled with hyphens (--test-every, --blender-half, --dry-run) spelled as defined."""
  out = []
  for arg in argv:
    name, equals, value = arg.partition("=")
    out.append(name.replace("-", "_").replace("__", "--", 1) + equals + value
               if name in HYPHENATED else arg)
  if any(a.startswith(("--config=", "-config=")) or a in ("--config", "-config")
         for a in out[1:]):
    return out
  return [out[0], "--config=auto", *out[1:]]


def standard_main(argv=None):
  """`python -m nerf_jax.bench.standard`."""
  given = list(sys.argv if argv is None else argv)
  command_line.run_command(define_standard_flags, standard, normalised_argv(given),
                           with_config=True)


if __name__ == "__main__":
  standard_main()
