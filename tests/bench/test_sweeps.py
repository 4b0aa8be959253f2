"""The benchmark: a tiny sweep end to end through its flags, its bookkeeping, its command lines
and the commands the docs show. Nothing here asserts on speed."""

import contextlib
import glob
import io
import json
import math
import os
import re
import shlex
import subprocess
import sys
import time

import imageio.v2 as imageio
import jax
import jax.numpy as jnp
import pytest
from absl import flags

from nerf_jax import cli
from nerf_jax.backend import errors
from nerf_jax.data import scenes
from nerf_jax.run import config_lib
from nerf_jax.bench import cli as bench_cli
from nerf_jax.bench import render as bench_render
from nerf_jax.bench import measure, profile, report, runner, sweeps, timed_run

from tests.bench import test_records
from tests.helpers import ROOT
RECORD_FIELDS = {
    "sweep", "label", "scene", "test_psnr", "test_ssim", "test_views", "psnr_at", "probes",
    "steps", "train_seconds", "compile_seconds", "step_ms", "rays_per_second", "mlp_gflops",
    "peak_fraction", "matmul_peak_gflops", "render_ms", "render_ms_samples", "params",
    "peak_rss_mb", "machine", "command", "config", "mode"}
MACHINE_FIELDS = {"cpu_model", "cpu_count", "device_kind", "jax", "jaxlib", "matmul_gflops"}


def _parse(define, program, *args, with_config=True):
  """(flag values, config spec, argv as given): `args` parsed as `program` parses them, on a
  private FlagValues (absl's global one can hold each flag only once per process)."""
  given = [program, *args]
  argv, spec = cli.resolve_config_argv(given) if with_config else (given, "")
  values = flags.FlagValues()
  define(values, argv)
  errors.parse_flags(argv, values)
  return values, spec, given


def _sweep(*args):
  """`python -m nerf_jax.bench ARGS`, in this process; returns the records."""
  return bench_cli.sweep(*_parse(bench_cli.define_sweep_flags, "nerf_jax.bench", *args))


def _records(out):
  return [json.loads(l) for l in (out / "results.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
  """Two configurations of the quick sweep on debug-sized data, 3 steps each (in this process:
  a worker subprocess per run would double the test's time; see the subprocess test below)."""
  out = tmp_path_factory.mktemp("bench")
  _sweep("--quick", "--only=default,samples=32", "--config=debug", "--config.model.width=16",
         "--steps=3", "--image_size=16", "--eval_views=1", "--eval_times=0.001,1000",
         "--render_repeats=2", "--matmul_repeats=2", "--in_process", f"--out={out}")
  return out


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
def test_tiny_sweep_writes_one_well_formed_record_per_configuration(tiny_sweep):
  records = _records(tiny_sweep)
  assert [r["label"] for r in records] == ["default", "samples=32"]
  for r in records:
    assert "error" not in r, r.get("error")
    assert RECORD_FIELDS <= set(r), RECORD_FIELDS - set(r)
    assert MACHINE_FIELDS <= set(r["machine"])
    test_records.assert_stamped(r, r["machine"])  # the sweep's machine, the run's load in it
    assert r["machine"]["load"] and r["machine"]["matmul_gflops"]
    assert r["steps"] == 3 and r["config"]["train"]["max_steps"] == 3
    # --config=debug is the base, --config.FIELD applies to every run, --image_size to the data.
    assert r["config"]["pos_encode_dims"] == 4 and r["config"]["model"]["width"] == 16
    assert r["config"]["data"]["image_size"] == 16
    assert r["test_views"] == 2 and math.isfinite(r["test_psnr"])
    assert -1.0 <= r["test_ssim"] <= 1.0
    assert r["compile_seconds"] > 0 and r["train_seconds"] >= r["compile_seconds"]
    assert len(r["render_ms_samples"]) == 2 and r["render_size"] == [100, 100]
    assert r["params"] > 0 and r["peak_rss_mb"] > 0
    assert r["peak_fraction"] == pytest.approx(r["mlp_gflops"] / r["matmul_peak_gflops"])
    assert r["probes"][0] == {"seconds": 0.0, "step": 0, "psnr": r["probes"][0]["psnr"]}
    assert r["probes"][-1]["step"] == 3
    # Probing at 1 ms: only the untrained model existed then (compiling takes longer).
    assert r["psnr_at"]["0.001"] == r["probes"][0]["psnr"]
    assert r["psnr_at"]["1000"] == r["probes"][-1]["psnr"]
  assert records[1]["config"]["num_samples"] == 32


def test_tiny_sweep_writes_the_table_and_valid_plots(tiny_sweep):
  table = (tiny_sweep / "results.md").read_text()
  assert "python -m nerf_jax.bench --quick" in table and "jax 0." in table
  rows = [l for l in table.splitlines() if l.startswith("| diffuse |")]
  assert [row.split("|")[2].strip() for row in rows] == ["default", "samples=32"]
  header = next(l for l in table.splitlines() if l.startswith("| scene |"))
  assert len(header.split("|")) == len(rows[0].split("|"))
  for name in report.PLOTS:
    image = imageio.imread(tiny_sweep / name)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100


@pytest.mark.slow  # a process
def test_a_run_in_a_subprocess_reports_its_failure_in_its_record():
  config = sweeps.make_config(sweeps.Entry("x"), "diffuse", base="debug")
  config.data.path = "/no/such/scene.npz"
  record = runner.run_isolated(config, timed_run.Options())
  assert record["error"].startswith("DataError") and "/no/such/scene.npz" in record["error"]


@pytest.mark.slow  # a process per run
def test_a_sweep_shows_progress_and_goes_on_past_failed_runs(tmp_path, capsys):
  bad = tmp_path / "bad.npz"
  bad.write_bytes(b"not an npz")
  _sweep("--quick", "--only=default,samples=32", "--config=debug", f"--scenes={bad}",
         "--steps=1", "--matmul_repeats=1", f"--out={tmp_path / 'out'}")
  records = _records(tmp_path / "out")
  assert [r["label"] for r in records] == ["default", "samples=32"]
  assert all("bad.npz" in r["error"] for r in records)
  shown = capsys.readouterr().out
  assert "sweep 2/2" in shown and shown.index("[2/2]") < shown.index("sweep 2/2")
  assert "sweep 1/2  50%" in shown and "<?" not in shown.split("sweep 1/2")[1].split("\n")[0]


def test_without_matplotlib_the_sweep_says_what_to_install_before_training(
    tmp_path, capsys, monkeypatch):
  monkeypatch.setitem(sys.modules, "matplotlib", None)  # `import matplotlib...` now fails
  assert report.missing_dependency() == 'plots need matplotlib: pip install -e ".[bench]"'
  capsys.readouterr()
  with pytest.raises(SystemExit) as info:
    _sweep("--quick", "--config=debug", "--steps=1", f"--out={tmp_path / 'out'}")
  assert info.value.code == 1
  captured = capsys.readouterr()
  assert captured.err.strip().splitlines() == [
      'error: plots need matplotlib: pip install -e ".[bench]"']
  assert captured.out == "" and not (tmp_path / "out").exists()  # nothing planned or trained
  assert _sweep("--quick", "--dry_run") == []  # listing the runs needs no plots


def _run(*args, **env):
  return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True,
                        env={**os.environ, "PYTHONPATH": ROOT, **env}, timeout=300)


@pytest.mark.slow  # three processes
def test_the_command_lists_its_runs_and_fails_in_one_line(tmp_path):
  res = _run("nerf_jax.bench", "--sweep=configs", "--config=debug", "--dry_run")
  assert res.returncode == 0, res.stderr
  assert "4 runs of 120 s of training each" in res.stdout
  assert "configs/fast on diffuse" in res.stdout
  res = _run("nerf_jax.bench", "--sweep=nope", "--dry_run")
  assert res.returncode == 1 and res.stderr.strip().splitlines() == [
      f"error: --sweep: unknown sweep(s) nope (valid: all, {', '.join(sweeps.SWEEPS)})"]
  # An installed package named matplotlib that cannot be imported: the check's one line.
  (tmp_path / "matplotlib").mkdir()
  (tmp_path / "matplotlib" / "__init__.py").write_text("raise ImportError('broken')\n")
  res = _run("nerf_jax.bench", "--quick", PYTHONPATH=f"{tmp_path}{os.pathsep}{ROOT}")
  assert res.returncode == 1 and res.stdout == "" and res.stderr.strip().splitlines() == [
      'error: plots need matplotlib: pip install -e ".[bench]"']


def test_config_flags_set_the_base_and_override_every_run():
  values, spec, _ = _parse(bench_cli.define_sweep_flags, "nerf_jax.bench", "--sweep=configs",
                           "--config=debug", "--config.seed=7", "--config.train.lr=0.01",
                           "--scenes=fog", "--budget_seconds=30")
  request, options, out = bench_cli.sweep_request(values, spec)
  assert request.overrides == {"seed": 7, "train.lr": 0.01} and out == "bench_out/configs"
  assert options.eval_times == (15, 30, 60, 120, 300, 600) and options.fit_schedule
  configs = {entry.label: config for _, entry, _, config in sweeps.plan(request)}
  debug, fast = config_lib.load("debug"), config_lib.load("fast")
  assert configs["default"].num_samples == debug.num_samples  # --config replaces default.py
  assert configs["fast"].model.encoding == fast.model.encoding  # other bases stay theirs
  for config in configs.values():
    assert config.seed == 7 and config.train.lr == 0.01 and config.data.scene == "fog"
    assert config.train.max_seconds == 30.0
  with pytest.raises(ValueError, match="--config.data.scene: the bench sets it; use --scenes"):
    sweeps.plan(sweeps.Request(overrides={"data.scene": "fog"}))


def _documented_commands():
  """Every `python -m nerf_jax.bench...` command in the code blocks of docs/*.md, continuation
  lines joined: [(page, module, args)]."""
  commands = []
  for path in sorted(glob.glob(os.path.join(ROOT, "docs", "*.md"))):
    with open(path) as f:
      text = f.read().replace("\\\n", " ")
    in_code = False
    for line in text.splitlines():
      if line.lstrip().startswith("```"):
        in_code = not in_code
      match = re.search(r"python -m (nerf_jax\.bench\S*)(.*)", line) if in_code else None
      if match:
        args = shlex.split(match.group(2).split("#")[0])
        commands.append((os.path.basename(path), match.group(1), args))
  return commands


def test_every_documented_command_parses(tmp_path, monkeypatch, capsys):
  monkeypatch.chdir(tmp_path)
  known = {"nerf_jax.bench", "nerf_jax.bench.render", "nerf_jax.bench.profile"}
  commands = _documented_commands()
  assert known <= {module for _, module, _ in commands}
  # The capture and hash-step measurements are scripts of their own (docs/capture.md,
  # docs/hashgrid.md); these are the sweep, render and profile command lines.
  commands = [c for c in commands if c[1] in known]
  for page, module, args in commands:
    for arg in args:  # dataset files and folders the command expects to exist
      if arg.startswith("--scenes="):
        for scene in arg.split("=", 1)[1].split(","):
          if scene.endswith(".npz"):
            (tmp_path / scene).touch()
          elif scene not in scenes.SCENES:  # a public dataset's folder (lego400, fern)
            (tmp_path / scene).mkdir(exist_ok=True)
    try:
      if module == "nerf_jax.bench":
        assert _sweep(*args, "--dry_run") == [], (page, args)
      elif module == "nerf_jax.bench.render":
        _parse(bench_render.define_render_flags, module, *args, with_config=False)
      else:
        _parse(profile.define_profile_flags, module, *args)
    except SystemExit as e:
      pytest.fail(f"{page}: python -m {module} {shlex.join(args)}: "
                  f"{capsys.readouterr().err.strip()} (exit {e.code})")


def test_recorded_results_still_make_their_report():
  paths = sorted(glob.glob(os.path.join(ROOT, "docs", "bench", "**", "results.jsonl"),
                          recursive=True))
  assert paths
  for path in paths:
    with open(path) as f:
      records = [json.loads(l) for l in f if l.strip()]
    lines = report.header_lines(records[0]) + report.table_lines(records)
    assert len(lines) > 2 + len(records), path


def test_psnr_at_times_takes_the_latest_probe_at_or_before_each_time():
  log = [{"seconds": 20.0, "step": 40, "psnr": 21.0}, {"seconds": 0.0, "step": 0, "psnr": 9.0},
         {"seconds": 14.2, "step": 30, "psnr": 18.5}, {"seconds": 31.0, "step": 70, "psnr": 24.0}]
  times = [-1.0, 0.0, 10.0, 14.2, 15.0, 30.0, 31.0, 1e6]
  assert measure.psnr_at_times(log, times) == [None, 9.0, 9.0, 18.5, 18.5, 21.0, 24.0, 24.0]
  assert measure.psnr_at_times([], [1.0]) == [None]


@pytest.mark.slow  # wall-clock
def test_compile_time_is_measured_apart_from_step_time():
  delay = 0.5

  @jax.jit
  def slow_to_compile(x):
    time.sleep(delay)  # runs while tracing, i.e. inside lower().compile(), never in a call
    return x + 1.0

  compiled, compile_seconds = measure.compile_jitted(slow_to_compile, jnp.zeros(4))
  assert compile_seconds >= delay
  steps = measure.sample_seconds(lambda: compiled(jnp.zeros(4)).block_until_ready(), 3)
  assert len(steps) == 3 and max(steps) < delay


@pytest.mark.slow  # wall-clock
def test_train_loop_counts_steps_pauses_the_clock_and_probes_before_each_time():
  clock = measure.Clock()
  clock.start()
  probed = []

  def probe(state):
    before = clock.seconds()
    time.sleep(0.01)
    assert clock.seconds() == before  # evaluation time is not training time
    probed.append(int(state))
    return float(state)

  step = lambda s: (s + 1, {"rays_in_loss": 10 * (s + 1), "psnr": jnp.float32(0.5) * s})
  state, steps, segments, probes, last = timed_run.train_loop(
      step, jnp.array(0), 40, 0.0, [0.0, 1e6], probe, clock)
  assert steps == int(state) == 40 == sum(n for n, _ in segments)
  assert segments[0][0] == 1  # the first step after compiling is timed alone
  assert len(probes) == 1 and probes[0]["step"] == probed[0] == segments[0][0]
  assert probes[0]["psnr"] == float(probed[0])
  # The stats of the step each probe follows, and of the last step, as Python numbers.
  assert probes[0]["train"] == {"rays_in_loss": 10, "psnr": 0.0}
  assert last == {"rays_in_loss": 400, "psnr": 19.5}
  assert type(last["rays_in_loss"]) is int


@pytest.mark.slow  # wall-clock
def test_train_loop_stops_on_the_clock_in_budget_mode():
  clock = measure.Clock()
  clock.start()
  step = lambda s: (time.sleep(0.01), (s + 1, {}))[1]
  _, steps, _, _, _ = timed_run.train_loop(step, jnp.array(0), 10**9, 0.2, [], None, clock)
  assert 1 <= steps < 10**9 and clock.seconds() >= 0.2


def test_pareto_front_keeps_the_runs_nothing_beats():
  costs = [10.0, 20.0, 5.0, 20.0, 40.0, 5.0]
  scores = [25.0, 24.0, 20.0, 27.0, 27.0, 19.0]
  assert report.pareto_front(costs, scores) == [2, 0, 3]


def test_mlp_flops_count_two_per_multiply_add_and_three_passes_per_step():
  config = config_lib.load("debug")
  params = {"coarse": {"layer_0": {"kernel": jnp.zeros((27, 32)), "bias": jnp.zeros(32)},
                       "output": {"kernel": jnp.zeros((32, 4)), "bias": jnp.zeros(4)}}}
  per_sample = 2 * (27 * 32 + 32 * 4)
  assert measure.mlp_flops_per_sample(params["coarse"]) == per_sample
  assert measure.mlp_flops_per_step(params, config, 10) == 3 * 10 * config.num_samples * per_sample


def test_sweeps_build_valid_configs():
  for name, entries in sweeps.SWEEPS.items():
    for entry in entries:
      config = sweeps.make_config(entry, "diffuse", {"seed": 3})
      assert config.seed == 3 and config.data.scene == "diffuse", (name, entry.label)
  keras = sweeps.make_config(sweeps.Entry("k", base="keras_seed"), "fog")
  assert keras.num_samples == 32 and keras.data.scene == "fog"
  with pytest.raises(ValueError, match="neither a built-in scene"):
    sweeps.scene_overrides("no/such/dataset.npz")
  with pytest.raises(ValueError, match="unknown sweep"):
    sweeps.sweep_names("samples,nope")


def test_scaling_plot_from_synthetic_records(tmp_path):
  records = [{"scene": "diffuse", "sweep": "scaling", "label": f"rays={n}", "rays_per_step": n,
              "config": {"num_samples": 64, "num_fine_samples": 0}, "step_ms": 0.01 * n}
             for n in (128, 1024, 8192)]
  assert report.samples_per_step(records[1]) == 1024 * 64
  report.plot_scaling(records, tmp_path / "scaling.png")
  image = imageio.imread(tmp_path / "scaling.png")
  assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
  assert "scaling" in sweeps.SWEEPS and sweeps.sweep_names("scaling") == ["scaling"]


@pytest.fixture(scope="module")
def profiled():
  """One `python -m nerf_jax.bench.profile --config=debug --config.train.batch_rays=32
  --repeats=1 --ops=4`, in this process: (the stage rows it returned, what it printed). Both
  profile tests read it (the stage table is printed with or without --ops; each profile
  compiles every stage of the step, about a minute on a loaded 2-core CPU)."""
  values, spec, given = _parse(profile.define_profile_flags, "nerf_jax.bench.profile",
                               "--config=debug", "--config.train.batch_rays=32", "--repeats=1",
                               "--ops=4")
  printed = io.StringIO()
  with contextlib.redirect_stdout(printed):
    rows = profile.profile_table(values, spec, given)
  return rows, printed.getvalue()


def test_profile_times_every_stage_of_the_step(profiled):
  rows, out = profiled
  stages = [r[0] for r in rows]
  assert stages[0] == "train step (all)" and "field fwd+bwd" in stages
  assert "32 rays" in rows[0][2]  # the override reached the profiled config
  assert all(ms > 0 for _, ms, _ in rows if not math.isnan(ms))
  assert "GFLOP/s" in rows[-1][2]
  assert "| train step (all) |" in out
  assert profile.median_ms(lambda x: x + 1, jnp.zeros(3), repeats=1) > 0


def test_profile_lists_the_steps_xla_operations_by_kind(profiled):
  _, out = profiled
  table = out.split("| XLA operation kind |")[1].splitlines()[2:]
  kinds = [line.split("|")[1].strip() for line in table if line.startswith("|")]
  assert len(kinds) == 5 and kinds[-1] == "all"  # the 4 asked for, then the total
  assert all(not kind[-1].isdigit() and "::" not in kind for kind in kinds)
  times = [float(line.split("|")[2]) for line in table if line.startswith("|")]
  assert all(t > 0 for t in times) and times[:4] == sorted(times[:4], reverse=True)
  assert times[-1] >= sum(times[:4])


def test_a_run_on_a_busy_machine_says_so_in_its_line_and_its_row():
  busy = {"busy": True, "busy_why": "load 3.1 on 2 CPUs"}
  record = {"test_psnr": 20.0, "test_ssim": 0.5, "steps": 3, "train_seconds": 1.0,
            "compile_seconds": 0.5, "step_ms": 10.0, "render_ms": 5.0, "machine": busy}
  assert runner.summary(record).endswith("ms/frame (busy: load 3.1 on 2 CPUs)")
  assert runner.summary({**record, "machine": {"busy": False}}).endswith("ms/frame")
  assert report.load_cell(busy) == "busy: load 3.1 on 2 CPUs"
  assert report.load_cell({"busy": False, "busy_why": None}) == "idle"
  assert report.load_cell({"cpu_count": 2}) == "–"  # a record from before the verdict
