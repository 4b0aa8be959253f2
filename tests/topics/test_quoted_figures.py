"""Every measured figure README.md quotes comes from a results file in docs/bench/ and agrees
with it, as do the pages that repeat them (the default run's transcript in docs/performance.md,
the suite's time in docs/usage.md and pyproject.toml, the throughput check's rates in
docs/standard_benchmark.md).

FIGURES says where each figure is quoted (a pattern of the text around it, one group per
figure) and where it comes from (a results file, the record's selecting fields, the key, the
decimals it is quoted with). A figure re-measured is changed in its results file first; this
test then names every page that still quotes the old one. A quote rephrased so that its
pattern no longer matches fails too: change the pattern with it.
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


DEFAULT_RUN = "default_run/metrics.json"
SUITE = "suite/suite.jsonl"
STANDARD = "standard/cpu_2026-11-28.jsonl"  # nerf_jax.bench.standard (docs/standard_benchmark.md)
STANDARD_NOW = "standard/cpu_2026-11-29.jsonl"  # fern and fox re-run idle; and at 1000 steps
STANDARD_NOW_RUNS = {"fern": "2026-11-29 05:02 UTC", "fox": "2026-11-29 05:12 UTC"}  # 10 min
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
    ("docs/standard_benchmark.md", r"fern ([\d.]+) dB, fox ([\d.]+) \(2026-11-29\), lego ([\d.]+)",
     [source(STANDARD_NOW, "psnr", 2, scene=s, date=STANDARD_NOW_RUNS[s]) for s in ("fern", "fox")]
     + [source(STANDARD, "psnr", 2, scene="lego")]),
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
    ("docs/standard_benchmark.md", r"\| lego \|.*?\| (\d+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|",
     [source(STANDARD, k, d, scene="lego") for k, d in
      (("steps", 0), ("psnr", 2), ("ssim", 3), ("lpips", 3))]),
    ("docs/standard_benchmark.md", r"\| fern \|.*?\| (\d+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| "
     r"[\d.]+ min \| ([\d.]+) \|",
     [source(STANDARD_NOW, k, d, scene="fern", date=STANDARD_NOW_RUNS["fern"]) for k, d in
      (("steps", 0), ("psnr", 2), ("ssim", 3), ("lpips", 3))]
     + [source(STANDARD_NOW, "psnr", 2, scene="fern", steps=1000)]),
    ("docs/standard_benchmark.md", r"\| fox \|.*?\| (\d+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| "
     r"[\d.]+ min \| ([\d.]+) \|",
     [source(STANDARD_NOW, k, d, scene="fox", date=STANDARD_NOW_RUNS["fox"]) for k, d in
      (("steps", 0), ("psnr", 2), ("ssim", 3), ("lpips", 3))]
     + [source(STANDARD_NOW, "psnr", 2, scene="fox", steps=1000)]),
] + [  # the README's table of the standard benchmark, row by row
    ("README.md", r"\| lego \|.*?\| (\d+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|",
     [source(STANDARD, k, d, scene="lego") for k, d in
      (("steps", 0), ("psnr", 2), ("ssim", 3), ("lpips", 3))])] + [
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
      source(STANDARD_NOW, "psnr", 2, scene="fern", date=STANDARD_NOW_RUNS["fern"])])] + [  # the throughput check's rates, config by config
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
  for quoted, (path, key, decimals, where) in zip(match.groups(), sources):
    value = record(path, where)
    for part in key.split("."):  # a dotted key reads a nested field: machine.steps_per_second
      value = value[part]
    expected = f"{value:{decimals}}" if decimals == "," else f"{value:.{decimals}f}"
    if quoted != expected:
      out.append((quoted, expected, f"docs/bench/{path} {where} {key}"))
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
