"""The benchmark: a tiny sweep end to end, and its bookkeeping. Nothing here asserts on speed."""

import json
import math
import time

import imageio.v2 as imageio
import jax
import jax.numpy as jnp
import pytest

from nerf_jax import bench, bench_plots, bench_sweeps

RECORD_FIELDS = {
    "sweep", "label", "scene", "test_psnr", "test_ssim", "test_views", "psnr_at", "probes",
    "steps", "train_seconds", "compile_seconds", "step_ms", "rays_per_second", "mlp_gflops",
    "peak_fraction", "matmul_peak_gflops", "render_ms", "render_ms_samples", "params",
    "peak_rss_mb", "machine", "command", "config", "mode"}
MACHINE_FIELDS = {"cpu_model", "cpu_count", "device_kind", "jax", "jaxlib", "matmul_gflops"}


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
  """Two configurations of the quick sweep on debug-sized data, 3 steps each (in this process:
  a worker subprocess per run would double the test's time; see the subprocess test below)."""
  out = tmp_path_factory.mktemp("bench")
  argv = ["--quick", "--only=default,samples=32", "--base=debug", "--steps=3",
          "--image_size=16", "--eval_views=1", "--eval_times=0.001,1000",
          "--render_repeats=2", "--matmul_repeats=2", "--in_process", f"--out={out}"]
  assert bench.main(argv) == 0
  return out


def test_tiny_sweep_writes_one_well_formed_record_per_configuration(tiny_sweep):
  records = [json.loads(l) for l in (tiny_sweep / "results.jsonl").read_text().splitlines()]
  assert [r["label"] for r in records] == ["default", "samples=32"]
  for r in records:
    assert "error" not in r, r.get("error")
    assert RECORD_FIELDS <= set(r), RECORD_FIELDS - set(r)
    assert MACHINE_FIELDS <= set(r["machine"])
    assert r["steps"] == 3 and r["config"]["train"]["max_steps"] == 3
    assert r["test_views"] == 2 and math.isfinite(r["test_psnr"])
    assert -1.0 <= r["test_ssim"] <= 1.0
    assert r["compile_seconds"] > 0 and r["train_seconds"] >= r["compile_seconds"]
    assert len(r["render_ms_samples"]) == 2 and r["params"] > 0 and r["peak_rss_mb"] > 0
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
  for name in bench_plots.PLOTS:
    image = imageio.imread(tiny_sweep / name)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100


def test_a_run_in_a_subprocess_reports_its_failure_in_its_record():
  config = bench_sweeps.make_config(bench_sweeps.Entry("x"), "diffuse", base="debug")
  config.data.path = "/no/such/scene.npz"
  record = bench.run_isolated(config, bench.Options())
  assert record["error"].startswith("DataError") and "/no/such/scene.npz" in record["error"]


def test_a_sweep_shows_progress_and_goes_on_past_failed_runs(tmp_path, capsys):
  bad = tmp_path / "bad.npz"
  bad.write_bytes(b"not an npz")
  argv = ["--quick", "--only=default,samples=32", "--base=debug", f"--scenes={bad}",
          "--steps=1", "--matmul_repeats=1", f"--out={tmp_path / 'out'}"]
  assert bench.main(argv) == 0
  records = [json.loads(l) for l in (tmp_path / "out" / "results.jsonl").read_text().splitlines()]
  assert [r["label"] for r in records] == ["default", "samples=32"]
  assert all("bad.npz" in r["error"] for r in records)
  shown = capsys.readouterr().out
  assert "sweep 2/2" in shown and shown.index("[2/2]") < shown.index("sweep 2/2")
  assert "sweep 1/2  50%" in shown and "<?" not in shown.split("sweep 1/2")[1].split("\n")[0]


def test_psnr_at_times_takes_the_latest_probe_at_or_before_each_time():
  log = [{"seconds": 20.0, "step": 40, "psnr": 21.0}, {"seconds": 0.0, "step": 0, "psnr": 9.0},
         {"seconds": 14.2, "step": 30, "psnr": 18.5}, {"seconds": 31.0, "step": 70, "psnr": 24.0}]
  times = [-1.0, 0.0, 10.0, 14.2, 15.0, 30.0, 31.0, 1e6]
  assert bench.psnr_at_times(log, times) == [None, 9.0, 9.0, 18.5, 18.5, 21.0, 24.0, 24.0]
  assert bench.psnr_at_times([], [1.0]) == [None]


def test_compile_time_is_measured_apart_from_step_time():
  delay = 0.5

  @jax.jit
  def slow_to_compile(x):
    time.sleep(delay)  # runs while tracing, i.e. inside lower().compile(), never in a call
    return x + 1.0

  compiled, compile_seconds = bench.compile_jitted(slow_to_compile, jnp.zeros(4))
  assert compile_seconds >= delay
  steps = bench.sample_seconds(lambda: compiled(jnp.zeros(4)).block_until_ready(), 3)
  assert len(steps) == 3 and max(steps) < delay


def test_train_loop_counts_steps_pauses_the_clock_and_probes_before_each_time():
  clock = bench.Clock()
  clock.start()
  probed = []

  def probe(state):
    before = clock.seconds()
    time.sleep(0.01)
    assert clock.seconds() == before  # evaluation time is not training time
    probed.append(int(state))
    return float(state)

  state, steps, segments, probes = bench.train_loop(
      lambda s: s + 1, jnp.array(0), 40, 0.0, [0.0, 1e6], probe, clock)
  assert steps == int(state) == 40 == sum(n for n, _ in segments)
  assert segments[0][0] == 1  # the first step after compiling is timed alone
  assert len(probes) == 1 and probes[0]["step"] == probed[0] == segments[0][0]
  assert probes[0]["psnr"] == float(probed[0])


def test_train_loop_stops_on_the_clock_in_budget_mode():
  clock = bench.Clock()
  clock.start()
  step = lambda s: (time.sleep(0.01), s + 1)[1]
  _, steps, _, _ = bench.train_loop(step, jnp.array(0), 10**9, 0.2, [], None, clock)
  assert 1 <= steps < 10**9 and clock.seconds() >= 0.2


def test_pareto_front_keeps_the_runs_nothing_beats():
  costs = [10.0, 20.0, 5.0, 20.0, 40.0, 5.0]
  scores = [25.0, 24.0, 20.0, 27.0, 27.0, 19.0]
  assert bench_plots.pareto_front(costs, scores) == [2, 0, 3]


def test_mlp_flops_count_two_per_multiply_add_and_three_passes_per_step():
  config = bench_sweeps.load_base("debug")  # 3 layers of 32, skip after layer 1, 4 bands
  params = {"coarse": {"layer_0": {"kernel": jnp.zeros((27, 32)), "bias": jnp.zeros(32)},
                       "output": {"kernel": jnp.zeros((32, 4)), "bias": jnp.zeros(4)}}}
  per_sample = 2 * (27 * 32 + 32 * 4)
  assert bench.mlp_flops_per_sample(params["coarse"]) == per_sample
  assert bench.mlp_flops_per_step(params, config, 10) == 3 * 10 * config.num_samples * per_sample


def test_sweeps_build_valid_configs():
  for name, entries in bench_sweeps.SWEEPS.items():
    for entry in entries:
      config = bench_sweeps.make_config(entry, "diffuse", {"seed": 3})
      assert config.seed == 3 and config.data.scene == "diffuse", (name, entry.label)
  keras = bench_sweeps.make_config(bench_sweeps.Entry("k", base="keras_seed"), "fog")
  assert keras.num_samples == 32 and keras.data.scene == "fog"
  with pytest.raises(ValueError, match="neither a built-in scene"):
    bench_sweeps.scene_overrides("no/such/dataset.npz")
  with pytest.raises(ValueError, match="unknown sweep"):
    bench_sweeps.sweep_names("samples,nope")


def test_scaling_plot_from_synthetic_records(tmp_path):
  records = [{"scene": "diffuse", "sweep": "scaling", "label": f"rays={n}", "rays_per_step": n,
              "config": {"num_samples": 64, "num_fine_samples": 0}, "step_ms": 0.01 * n}
             for n in (128, 1024, 8192)]
  assert bench_plots.samples_per_step(records[1]) == 1024 * 64
  bench_plots.plot_scaling(records, tmp_path / "scaling.png")
  image = imageio.imread(tmp_path / "scaling.png")
  assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
  assert "scaling" in bench_sweeps.SWEEPS and bench_sweeps.sweep_names("scaling") == ["scaling"]


def test_profile_times_every_stage_of_the_step():
  from nerf_jax import bench_profile
  config = bench_sweeps.load_base("debug")
  config.train.batch_rays = 32
  rows = bench_profile.profile(config, repeats=1)
  stages = [r[0] for r in rows]
  assert stages[0] == "train step (all)" and "field fwd+bwd" in stages
  assert all(ms > 0 for _, ms, _ in rows if not math.isnan(ms))
  assert "GFLOP/s" in rows[-1][2]
