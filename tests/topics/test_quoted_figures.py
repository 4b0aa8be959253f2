"""Every measured figure README.md quotes comes from a results file in docs/bench/ and agrees
with it, as do the pages that repeat them (the default run's transcript in docs/performance.md,
the suite's time in docs/usage.md and pyproject.toml, the throughput check's rates in
docs/standard_benchmark.md), and so does each manual page's headline figure whose record is kept.

FIGURES says where each figure is quoted (a pattern of the text around it, one group per
figure) and where it comes from (a results file, the record's selecting fields, the key, the
decimals it is quoted with). A few records live beside docs/bench (docs/regret/, docs/gpu_runs/):
their paths start with `../`. A gain or a distance to a goal ("+2.77 dB", "short by 2.37") is a
difference(first, second, decimals): first minus second, each a source or a number (a goal);
the page's sign stays in the pattern, outside the group. A figure re-measured is changed in its
results file first; this test then names every page that still quotes the old one. A quote
rephrased so that its pattern no longer matches fails too: change the pattern with it.
"""

import json
import pathlib
import re

import pytest

from tests.helpers import ROOT

ROOT = pathlib.Path(ROOT)
BENCH = ROOT / "docs" / "bench"


def source(path, key, decimals, **where):
  """(results file relative to docs/bench, key (dotted for a nested field), decimals (or ','
  for an integer with thousands separators), the record's selecting fields)."""
  return (path, key, decimals, where)


def difference(first, second, decimals):
  """A figure quoted as `first` minus `second` (each a source(...) or a number), at `decimals`."""
  return ("difference", (first, second), decimals, {})


DEFAULT_RUN = "default_run/metrics.json"
SUITE = "suite/suite.jsonl"
STANDARD = "standard/cpu_2026-11-28.jsonl"  # nerf_jax.bench.standard (docs/standard_benchmark.md)
STANDARD_NOW = "standard/cpu_2026-11-29.jsonl"  # the three re-run idle; and at 1000 steps
STANDARD_NOW_RUNS = {"lego": "2026-11-29 06:07 UTC", "fern": "2026-11-29 05:02 UTC",
                     "fox": "2026-11-29 05:12 UTC"}  # the 10-minute rows
LEGO_COPY = "standard/lego_400_copy_check_2026-11-29.json"  # the 400 px copy against --blender_half
FERN_AGAIN = "2026-11-29 05:45 UTC"  # fern trained by steps to its row's 4576
THROUGHPUT = "throughput/cpu.jsonl"  # nerf_jax.bench.throughput: the first idle 2-core records
THROUGHPUT_RUNS = {"default": "2026-11-29 04:02 UTC", "fast": "2026-11-29 04:03 UTC",
                   "detail": "2026-11-29 04:04 UTC", "capture": "2026-11-29 04:04 UTC",
                   "llff": "2026-11-29 04:05 UTC", "hash": "2026-11-29 04:06 UTC",
                   "mipnerf": "2026-11-29 04:07 UTC"}  # config: the date of its quoted record
SIDE_BY_SIDE = "throughput/default_side_by_side_2026-11-29.jsonl"  # default.py, code before/after
CI_RUN = (("tests", 0), ("minutes", 1))  # the suite as .ci/run measures it
FIGURES = [
    ("README.md", r"test PSNR ([\d.]+) dB after (\d+) steps",
     [source(DEFAULT_RUN, "psnr", 2), source(DEFAULT_RUN, "steps", 0)]),
    ("docs/performance.md",
     r"test PSNR ([\d.]+) dB, SSIM ([\d.]+), LPIPS ([\d.]+) over 20 views after (\d+) steps",
     [source(DEFAULT_RUN, "psnr", 2), source(DEFAULT_RUN, "ssim", 4),
      source(DEFAULT_RUN, "lpips", 4), source(DEFAULT_RUN, "steps", 0)]),
    ("README.md", r"(\d+) tests in ([\d.]+) min",
     [source(SUITE, key, decimals, command=".ci/run") for key, decimals in CI_RUN]),
    ("docs/usage.md", r"Now: (\d+) tests in ([\d.]+) min",
     [source(SUITE, key, decimals, command=".ci/run") for key, decimals in CI_RUN]),
    ("pyproject.toml", r"take ([\d.]+) min where one takes ([\d.]+)",
     [source(SUITE, "minutes", 1, workers=2, tests=631),
      source(SUITE, "minutes", 1, workers=1, tests=631)]),
    ("docs/performance.md", r"`default.py` ([\d.]+) / ([\d.]+) / ([\d.]+) dB at 60 / 300 / 900 s",
     [source(f"centres/configs{t}/results.jsonl", "test_psnr", 2, label="default")
      for t in (60, 300, 900)]),
    ("docs/performance.md", r"the Keras reference: ([\d.]+)–([\d.]+)",
     [source("configs/results.jsonl", "test_psnr", 1, label="keras_seed"),
      source("configs900/results.jsonl", "test_psnr", 1, label="keras_seed")]),
    ("docs/performance.md", r"`fast.py` ([\d.]+) dB after 300 s, (\d+) ms a frame",
     [source("centres/configs300/results.jsonl", "test_psnr", 2, label="fast"),
      source("centres/configs300/results.jsonl", "render_ms", 0, label="fast")]),
    ("docs/accuracy.md", r"16 samples reach ([\d.]+) dB, 64 samples ([\d.]+)",
     [source("centres/samples/results.jsonl", "test_psnr", 2, label=f"samples={n}")
      for n in (16, 64)]),
    ("docs/detail_scene.md", r"`detail` ([\d.]+) dB with",
     [source("detail/ten_minutes/detail_py.jsonl", "test_psnr", 2, scene="detail")]),
    ("docs/standard_benchmark.md", r"lego ([\d.]+) dB at 400 px, fern ([\d.]+), fox ([\d.]+)",
     [source(STANDARD_NOW, "psnr", 2, scene=s, date=STANDARD_NOW_RUNS[s])
      for s in ("lego", "fern", "fox")]),
    ("docs/standard_benchmark.md", r"by steps to the fern row's (\d+) .*?fern scored ([\d.]+) dB "
     r"against the row's ([\d.]+)\.",
     [source(STANDARD_NOW, "steps", 0, scene="fern", date=STANDARD_NOW_RUNS["fern"]),
      source(STANDARD_NOW, "psnr", 2, scene="fern", date=FERN_AGAIN),
      source(STANDARD_NOW, "psnr", 2, scene="fern", date=STANDARD_NOW_RUNS["fern"])]),
    ("docs/standard_benchmark.md", r"Fern made (\d+) steps in ten minutes on the VM of 2026-11-28 "
     r"\(([\d.]+) dB\) and (\d+) on that of 2026-11-29 \(([\d.]+) dB\)",
     [source(STANDARD, "steps", 0, scene="fern"), source(STANDARD, "psnr", 2, scene="fern"),
      source(STANDARD_NOW, "steps", 0, scene="fern", date=STANDARD_NOW_RUNS["fern"]),
      source(STANDARD_NOW, "psnr", 2, scene="fern", date=STANDARD_NOW_RUNS["fern"])]),
    ("docs/standard_benchmark.md", r"lego (\d+) and (\d+) \(([\d.]+) and ([\d.]+) dB\)",
     [source(STANDARD, "steps", 0, scene="lego"),
      source(STANDARD_NOW, "steps", 0, scene="lego", date=STANDARD_NOW_RUNS["lego"]),
      source(STANDARD, "psnr", 2, scene="lego"),
      source(STANDARD_NOW, "psnr", 2, scene="lego", date=STANDARD_NOW_RUNS["lego"])]),
    ("docs/standard_benchmark.md", r"agree to ([\d.]+)–([\d.]+) dB on white,\s+near 8-bit "
     r"rounding's ([\d.]+)",
     [source(LEGO_COPY, key, 1) for key in ("min_psnr", "max_psnr", "eight_bit_rounding_psnr")]),
] + [  # the standard benchmark's table, row by row
    ("docs/standard_benchmark.md",
     rf"\| {scene} \|.*?\| (\d+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| "
     r"[\d.]+ min \| ([\d.]+) \|",
     [source(STANDARD_NOW, k, d, scene=scene, date=date) for k, d in
      (("steps", 0), ("psnr", 2), ("ssim", 3), ("lpips", 3))]
     + [source(STANDARD_NOW, "psnr", 2, scene=scene, steps=1000)])
    for scene, date in STANDARD_NOW_RUNS.items()] + [  # the README's table, row by row

    ("README.md", rf"\| {scene} \|.*?\| (\d+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| "
     r"idle \(others ([\d.]+) CPU\), ([\d.]+) steps/s \|",
     [source(STANDARD_NOW, k, d, scene=scene, date=date) for k, d in
      (("steps", 0), ("psnr", 2), ("ssim", 3), ("lpips", 3))] +
     [source(STANDARD_NOW, "psnr", 2, scene=scene, steps=1000),
      source(STANDARD_NOW, "machine.others_cpu.mean", 2, scene=scene, date=date),
      source(STANDARD_NOW, "machine.steps_per_second", 2, scene=scene, date=date)])
    for scene, date in STANDARD_NOW_RUNS.items()] + [
    ("README.md", r"fern run made ([\d,]+) steps on the VM of 2026-11-28 \(([\d.]+) dB\) and "
     r"([\d,]+) on that of 2026-11-29 \(([\d.]+) dB\)",
     [source(STANDARD, "steps", ",", scene="fern"), source(STANDARD, "psnr", 2, scene="fern"),
      source(STANDARD_NOW, "steps", ",", scene="fern", date=STANDARD_NOW_RUNS["fern"]),
      source(STANDARD_NOW, "psnr", 2, scene="fern", date=STANDARD_NOW_RUNS["fern"])])] + [
    # the throughput check's rates, config by config
    ("docs/standard_benchmark.md", rf"\| `{config}` \| \w+ \| (\d+) \| ([\d.]+) \| (\d+) \|",
     [source(THROUGHPUT, k, d, config=config, date=date) for k, d in
      (("rays_per_step", 0), ("steps_per_second", 2), ("rays_per_second", 0))])
    for config, date in THROUGHPUT_RUNS.items()] + [  # why the check takes a median
    ("docs/standard_benchmark.md", r"`default` ran ([\d.]+) steps/s against ([\d.]+)",
     [source(THROUGHPUT, "steps_per_second", 2, config="default", date=date)
      for date in ("2026-11-29 05:14 UTC", THROUGHPUT_RUNS["default"])]),
    ("docs/standard_benchmark.md", r"\(([\d.]+) / ([\d.]+), ([\d.]+) / ([\d.]+), ([\d.]+) / "
     r"([\d.]+) steps/s;",
     [source(SIDE_BY_SIDE, "steps_per_second", 1, round=k, code=code) for k in (1, 2, 3)
      for code in ("before (62c8e68)", "after (49a1904)")])]
PERFORMANCE = "centres/configs300/results.jsonl"  # 300 s on diffuse, pixel centres
PHOTOS = "photos/results.jsonl"  # appearance codes and pose refinement at 90 s each
LEGO_400 = "detail/ten_minutes/detail_py.jsonl"  # detail.py, ten minutes, 2026-11-25
LANDMARK = "collections/landmark_2026-11-29.jsonl"
REGRET = "../regret/table60_steps/summary.jsonl"  # auto's regret, 60 s a run, 2026-11-28
LEGO_MS = "../regret/lego_ms600.jsonl"  # multiscale lego, 600 s a run
GPU_LEGO = ("../gpu_runs/h200_2026-11-28/frontier.json", "scenes.lego.record.test_psnr", 2, {})
FIGURES += [  # the other pages' headline figures
    ("docs/performance.md", r"marching\): ([\d.]+) dB \((\d+) steps\), (\d+) ms per frame",
     [source(PERFORMANCE, k, d, label="fast") for k, d in
      (("test_psnr", 2), ("steps", 0), ("render_ms", 0))]),
    ("docs/performance.md", r"8×64 MLP\): ([\d.]+) dB \((\d+) steps, ([\d.]+) ms per step\)",
     [source(PERFORMANCE, k, d, label="default") for k, d in
      (("test_psnr", 2), ("steps", 0), ("step_ms", 1))]),
    ("docs/detail_scene.md", r"`detail` [\d.]+ dB with SSIM ([\d.]+), LPIPS ([\d.]+) after (\d+)",
     [source("detail/ten_minutes/detail_py.jsonl", k, d, scene="detail") for k, d in
      (("test_ssim", 3), ("test_lpips", 3), ("steps", 0))]),
    ("docs/accuracy.md", r"\((\d+) vs (\d+) ms a step\)",
     [source("precision_remat/results.jsonl", "step_ms", 0, label=label)
      for label in ("bf16 8x64", "f32 8x64")]),
    ("docs/effects.md", r"pays \(\+([\d.]+) dB on RGB-only",
     [difference(*(source("effects/results.jsonl", "test_psnr", 1, scene="white_rgb.npz",
                          label=label) for label in ("+white_bg", "baseline")), 1)]),
    ("docs/gpu.md", r"\*\*([\d.]+) dB\*\* on lego \(400²\) in 60 s \(goal 35: short by ([\d.]+)\)",
     [GPU_LEGO, difference(35, GPU_LEGO, 2)]),
    ("docs/regret.md", r"0 on fog, forward and glossy, ([\d.]+)–([\d.]+) dB on crowd",
     [source(REGRET, "regret", 2, scene=scene) for scene in ("exposure", "diffuse")]),
    ("docs/transient_head.md", r"([\d.]+) dB without it against ([\d.]+) with it in (\d+) s, "
     r"fast.py ([\d.]+) against ([\d.]+) in (\d+) s",
     [source("transient/runs.jsonl", k, d, config=config, dims=dims)
      for config in ("default", "fast") for k, d, dims in
      (("psnr", 2, 0), ("psnr", 2, 16), ("seconds", 0, 0))]),
] + [  # the codes' gain and their cost at equal time (the sign in the pattern)
    ("docs/appearance_and_poses.md", pattern, [
        difference(source(PHOTOS, "test_psnr", 2, scene="exposure",
                          label="appearance codes, own looks"),
                   source(PHOTOS, "test_psnr", 2, scene="exposure", label="fast, own looks"), 2),
        difference(source(PHOTOS, "test_psnr", 2, scene="diffuse", label="fast"),
                   source(PHOTOS, "test_psnr", 2, scene="diffuse", label="appearance codes"), 2)])
    for pattern in (r"\+([\d.]+) dB on the photos that need them, at most −([\d.]+) where",
                    r"\*\*\+([\d.]+) dB\*\* on `exposure` .*? cost at most ([\d.]+) dB on")] + [
    ("docs/appearance_and_poses.md", r"loses ([\d.]+)–([\d.]+) dB where the poses are right",
     [difference(source(PHOTOS, "test_psnr", 1, scene=scene, label="fast"),
                 source(PHOTOS, "test_psnr", 1, scene=scene, label="pose refinement"), 1)
      for scene in ("exposure", "diffuse")])] + [
    (page, pattern + r"([\d.]+) dB\**,? mean over scales,? against ([\d.]+)",
     [source(LEGO_MS, "mean_over_scales_psnr", 2, run=run) for run in ("auto", "flip/cones")])
    for page, pattern in (("docs/multiscale.md", r"10 CPU-minutes, "),
                          ("docs/multiscale.md", r"\*\*"))] + [
    ("docs/photo_collections.md", r"([\d.]+) → ([\d.]+) dB at (\d+) steps",
     [source(LANDMARK, "psnr", 2, run="landmark_sfm, auto, depth off"),
      source(LANDMARK, "psnr", 2,
             run="landmark_sfm, intrinsics + pose refinement, no photo_zoom, depth on"),
      source(LANDMARK, "steps", 0, run="landmark_sfm, auto, depth off")])] + [
    ("docs/photo_collections.md", pattern,
     [source("collections/sacre_coeur_2026-11-29.jsonl", "psnr", 2, run="Sacre-Coeur, depth off")])
    for pattern in (r"photos of Sacré-Cœur: ([\d.]+) dB", r"scored \*\*([\d.]+) dB\*\*")] + [
    ("docs/photo_collections.md", r"without masks; with it on, ([\d.]+)\)",
     [source("collections/sacre_coeur_2026-11-29.jsonl", "psnr", 2,
             run="Sacre-Coeur (nerf-process --nosingle_camera), auto (depth on, kl)")])] + [
    ("docs/quality_per_second.md", r"lego at 400 px: ([\d.]+) dB and SSIM ([\d.]+) in ten minutes "
     r"\((\d+) steps, 2026-11-25.*?: ([\d.]+) in (\d+)\), ([\d.]+) dB and ([\d.]+) short",
     [source(LEGO_400, "test_psnr", 2, scene="lego400"),
      source(LEGO_400, "test_ssim", 3, scene="lego400"),
      source(LEGO_400, "steps", 0, scene="lego400"),
      source(STANDARD_NOW, "psnr", 2, scene="lego", date=STANDARD_NOW_RUNS["lego"]),
      source(STANDARD_NOW, "steps", 0, scene="lego", date=STANDARD_NOW_RUNS["lego"]),
      difference(30, source(LEGO_400, "test_psnr", 2, scene="lego400"), 2),
      difference(0.95, source(LEGO_400, "test_ssim", 3, scene="lego400"), 3)]),
    ("docs/quality_per_second.md", r"22.76 dB in ten minutes \(4458 steps.*?: ([\d.]+) in (\d+) "
     r"steps, 2026-11-29\)",
     [source(STANDARD_NOW, k, d, scene="fern", date=STANDARD_NOW_RUNS["fern"])
      for k, d in (("psnr", 2), ("steps", 0))])] + [
    ("docs/quality_per_second.md", rf"\| {pattern} \| `configs/detail.py` \| \**([\d.]+) / "
     r"([\d.]+) / ([\d.]+)\** \| (\d+) \|",
     [source(LEGO_400, k, d, scene=scene) for k, d in
      (("test_psnr", 2), ("test_ssim", 3), ("test_lpips", 3), ("steps", 0))])
    for pattern, scene in ((r"lego 400 px \(25 test views\)", "lego400"),
                           ("built-in `detail` 400 px", "detail"))]


def figure(src):
  """The value a source(...), a difference(...) or a number gives, and where it comes from."""
  if isinstance(src, (int, float)):
    return src, str(src)
  path, key, _, where = src
  if path == "difference":
    (first, first_from), (second, second_from) = (figure(s) for s in key)
    return first - second, f"{first_from} minus {second_from}"
  value = record(path, where)
  for part in key.split("."):  # a dotted key reads a nested field: machine.steps_per_second
    value = value[part]
  return value, f"docs/bench/{path} {where} {key}"


def record(path, where):
  """The last record of docs/bench/`path` (a .json, or a .jsonl of one record a line) whose
  fields match `where`."""
  text = (BENCH / path).read_text()
  records = ([json.loads(l) for l in text.splitlines() if l.strip()] if path.endswith(".jsonl")
             else [json.loads(text)])
  matching = [r for r in records if all(r.get(k) == v for k, v in where.items())]
  assert matching, f"docs/bench/{path} has no record with {where}"
  return matching[-1]


def disagreements(text, pattern, sources):
  """(quoted, from the results file, the file) for each figure of `pattern` in `text` that
  its source does not give; [('missing', pattern, '')] if `text` does not quote it."""
  match = re.search(pattern, " ".join(text.split()))  # a quote may run over a line break
  if match is None:
    return [("missing", pattern, "")]
  out = []
  for quoted, src in zip(match.groups(), sources):
    value, where_from = figure(src)
    decimals = src[2]
    expected = f"{value:{decimals}}" if decimals == "," else f"{value:.{decimals}f}"
    if quoted != expected:
      out.append((quoted, expected, where_from))
  return out


@pytest.mark.parametrize("page,pattern,sources", FIGURES,
                         ids=[f"{p}:{s[0][0]}" for p, _, s in FIGURES])
def test_the_quoted_figure_is_its_results_files(page, pattern, sources):
  assert disagreements((ROOT / page).read_text(), pattern, sources) == []


def test_the_check_catches_a_stale_figure():
  pattern, sources = FIGURES[5][1], FIGURES[5][2]
  text = "`default.py` 28.12 / 31.15 / 32.40 dB at 60 / 300 / 900 s"
  assert [d[:2] for d in disagreements(text, pattern, sources)] == [("32.40", "32.47")]
  assert disagreements("rephrased", pattern, sources)[0][0] == "missing"


def test_a_difference_is_its_first_source_minus_its_second():
  pattern, sources = r"short by ([\d.]+)", [difference(30, 29.57, 2)]
  assert disagreements("short by 0.43", pattern, sources) == []
  assert disagreements("short by 0.53", pattern, sources) == [("0.53", "0.43", "30 minus 29.57")]
