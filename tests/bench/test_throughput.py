"""bench.throughput: the comparison of a rate with the last one on the same kind of machine, on
records written here, and one real run of the command on configs/debug.py for a few steps.
Nothing here asserts on speed."""

import json

import pytest
from absl import flags

from nerf_jax.backend import errors
from nerf_jax.bench import throughput
from nerf_jax.run import machine
from tests.bench import test_records

IDLE = {"cpu_model": "AMD EPYC", "cpu_count": 2, "cpus_used": 2, "backend": "cpu",
        "device_kind": "cpu", "busy": False, "git": "a" * 40}


def _record(rate, config="fast", date="d", **machine_fields):
  return {"config": config, "scene": "diffuse", "image_size": 64, "rays_per_step": 2048,
          "steps_per_second": rate, "rays_per_second": 2048 * rate, "date": date,
          "machine": {**IDLE, **machine_fields}}


def test_the_baseline_is_the_median_of_the_last_three_idle_records():
  history = [_record(50.0, date="0"), _record(10.0, date="1"), _record(30.0, date="2"),
             _record(20.0, date="3"), _record(99.0, date="4", busy=True)]
  assert throughput.baseline(_record(9.0), history)["date"] == "3"  # 20 of 10, 30, 20
  assert throughput.baseline(_record(9.0), history[:2])["date"] == "0"  # of two, the upper
  assert throughput.baseline(_record(9.0), history[1:2])["date"] == "1"


def test_the_baseline_is_an_idle_record_of_the_same_work_and_kind():
  history = [_record(10.0, date="1"), _record(11.0, date="2"), _record(30.0, cpu_count=16),
             _record(40.0, backend="gpu", device_kind="H200"), _record(50.0, config="hash"),
             _record(60.0, rays_per_step=4096), _record(5.0, date="3", busy=True)]
  history[5]["rays_per_step"] = 4096
  now = _record(10.5)
  assert throughput.baseline(now, history)["date"] == "2"  # the upper of two; the busy 5.0 skipped
  assert throughput.baseline(_record(9.0, cpu_count=16), history)["steps_per_second"] == 30.0
  assert throughput.baseline(_record(9.0, cpus_used=1), history) is None  # pinned: another kind
  assert throughput.baseline(_record(9.0, config="llff"), history) is None


@pytest.mark.parametrize("now, verdict", [(8.4, "slower"), (8.6, "ok"), (11.4, "ok"),
                                          (11.6, "faster")])
def test_more_than_15_percent_slower_is_a_slowdown(now, verdict):
  ratio, said = throughput.judge(_record(now), _record(10.0))
  assert ratio == pytest.approx(now / 10.0) and said == verdict


def test_a_busy_run_is_not_judged_and_says_so():
  now = _record(5.0, busy=True, busy_why="load 3.1 on 2 CPUs")
  ratio, verdict = throughput.judge(now, _record(10.0))
  assert (ratio, verdict) == (pytest.approx(0.5), "busy")
  line = throughput.line(now, _record(10.0, date="2026-11-28"), ratio, verdict)
  assert line == ("fast: 5.00 steps/s (10,240 rays/s) now, 10.00 before (2026-11-28, code "
                  "aaaaaaaaaaaa), ratio 0.50: busy (busy: load 3.1 on 2 CPUs)")
  assert throughput.judge(now, None) == (None, "first")
  assert throughput.line(_record(5.0), None, None, "first") == (
      "fast: 5.00 steps/s (10,240 rays/s) now, no earlier record on an idle machine of this "
      "kind: first")


def _command(*args):
  """`python -m nerf_jax.bench.throughput ARGS` in this process; its verdicts."""
  argv = ["throughput", *args]
  values = flags.FlagValues()
  throughput.define_throughput_flags(values, argv)
  errors.parse_flags(argv, values)
  return throughput.throughput(values, "", argv)


@pytest.mark.slow  # compiles a train step (several seconds on 2 cores)
def test_a_tiny_run_records_and_flags_a_slowdown(tmp_path, monkeypatch, capsys):
  out = tmp_path / "throughput" / "cpu.jsonl"
  out.parent.mkdir()
  here = machine.describe()
  # An earlier record of the same work on this kind of machine at an impossible rate.
  before = {"config": "debug", "scene": "diffuse", "image_size": 16, "rays_per_step": 256,
            "steps_per_second": 1e9, "date": "earlier",
            "machine": {**here, "busy": False, "git": "b" * 40}}
  out.write_text(json.dumps(before) + "\n")
  monkeypatch.setattr(machine, "verdict", lambda *_: (False, None))  # an idle machine
  args = ("--configs=debug", "--steps=3", "--warmup=1", "--image_size=16", "--num_views=4",
          f"--out={out}")
  with pytest.raises(SystemExit) as stopped:
    _command(*args, "--check")
  assert stopped.value.code == 1
  records = [json.loads(l) for l in out.read_text().splitlines()]
  assert len(records) == 2 and records[0] == before
  record = records[1]
  assert (record["config"], record["scene"], record["image_size"], record["num_views"],
          record["steps"], record["warmup_steps"]) == ("debug", "diffuse", 16, 4, 3, 1)
  assert record["rays_per_step"] == record["batch_rays"] == 256
  assert record["steps_per_second"] == pytest.approx(3 / record["seconds"], rel=0.02)
  assert record["rays_per_second"] == pytest.approx(256 * record["steps_per_second"])
  assert record["machine"]["busy"] is False and record["machine"]["cpu_count"] >= 1
  assert record["command"].endswith(f"--out={out} --check")
  test_records.assert_stamped(record, record["machine"])  # date, git, the timed steps' machine
  assert record["machine"]["load"] and "others_cpu" in record["machine"]  # measured while timed
  printed = capsys.readouterr().out
  assert "before (earlier, code bbbbbbbbbbbb), ratio 0.00: slower\n" in printed
  assert "1 configs -> " in printed and "; slower: debug" in printed
  with pytest.raises(ValueError, match="nosuch"):  # a misspelt config: before any timing
    _command("--configs=nosuch", f"--out={out}")
