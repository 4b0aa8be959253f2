"""run/machine.py: the machine record's fields and types, the load over a run from samples
written here (against the arithmetic done by hand), the busy verdict both ways, the rates, and
the record in a trained run's metrics.json."""

import gc
import json
import re
import socket
import time

import pytest

from nerf_jax.run import machine

TYPES = {"cpu_model": str, "cpu_count": int, "cpus_used": int, "platform": str, "python": str,
         "jax": str, "jaxlib": str, "backend": str, "device_kind": str, "device_count": int,
         "devices": list, "seconds": float, "samples": int, "busy": bool, "busy_rule": str}


def _check_record(record):
  for field, kind in TYPES.items():
    assert isinstance(record[field], kind), (field, record[field])
  assert 1 <= record["cpus_used"] <= record["cpu_count"]
  assert record["memory_gb"] is None or record["memory_gb"] > 0
  assert len(record["devices"]) == record["device_count"] >= 1
  assert record["git"] is None or re.fullmatch(r"[0-9a-f]{40}(-dirty)?", record["git"])
  assert record["load"] is None or set(record["load"]) == {"start", "end", "mean", "max"}
  others = record["others_cpu"]
  assert others is None or 0 <= others["mean"] <= others["max"]
  assert (record["busy_why"] is None) == (not record["busy"])
  host = socket.gethostname()
  assert len(host) < 4 or host not in json.dumps(record)  # no host name


def test_a_sampled_record_has_every_field_typed(monkeypatch):
  monkeypatch.setattr(machine, "MIN_INTERVAL", 0.05)
  sampler = machine.Sampler(every=0.02)
  end = time.monotonic() + 0.2
  while time.monotonic() < end:  # this process busy: its own time is not the others'
    pass
  record = sampler.stop()
  _check_record(record)
  assert record["samples"] >= 3 and record["seconds"] >= 0.2
  assert sampler.stop() is record  # stopped once
  json.dumps(record)  # a JSON record


def test_a_dropped_sampler_ends_its_thread():
  sampler = machine.Sampler(every=0.01)
  thread = sampler._thread  # pylint: disable=protected-access
  del sampler
  gc.collect()
  thread.join(timeout=2.0)
  assert not thread.is_alive()


def test_git_revision_is_none_outside_a_checkout_of_the_package(tmp_path, monkeypatch):
  revision = machine.git_revision()
  assert revision is None or re.fullmatch(r"[0-9a-f]{40}(-dirty)?", revision)
  monkeypatch.setattr(machine, "ROOT", str(tmp_path))  # no git checkout there
  assert machine.git_revision() is None


def _sample(t, load, busy, own):
  return {"time": t, "load": load, "busy": busy, "own": own}


def test_load_summary_of_samples_against_the_arithmetic():
  # 2 CPUs, 100 ticks a second. 0-5 s: the CPUs busy 800 ticks, 600 of them this process: the
  # others took 200 ticks = 2 core-seconds over 5 s = 0.2 of each CPU. 5-10 s: 900 busy, 300
  # own: 6 core-seconds over 5 s = 0.6 of each. 10-10.5 s: 50 busy, 50 own: none, but half a
  # second is under MIN_INTERVAL: in the mean, not the max.
  samples = [_sample(0.0, 1.0, 1000, 100), _sample(5.0, 2.0, 1800, 700),
             _sample(10.0, 3.5, 2700, 1000), _sample(10.5, 3.0, 2750, 1050)]
  summary = machine.load_summary(samples, cpus_used=2, ticks_per_second=100)
  assert summary["seconds"] == 10.5 and summary["samples"] == 4
  assert summary["load"] == {"start": 1.0, "end": 3.0, "mean": 2.38, "max": 3.5}
  others_ticks = (2750 - 1000) - (1050 - 100)
  assert summary["others_cpu"]["mean"] == pytest.approx(others_ticks / 100 / 10.5 / 2, abs=1e-3)
  assert summary["others_cpu"]["max"] == pytest.approx(0.6)
  # Own ticks counted late can exceed the CPUs' busy ticks of an interval: no negative share.
  late = [_sample(0.0, 1.0, 0, 0), _sample(2.0, 1.0, 100, 150)]
  assert machine.load_summary(late, 1, 100)["others_cpu"] == {"mean": 0.0, "max": 0.0}
  # Without /proc (busy None) or under MIN_INTERVAL, others_cpu is not measured.
  unmeasured = [_sample(0.0, 0.5, None, None), _sample(6.0, 0.7, None, None)]
  assert machine.load_summary(unmeasured, 2, 100)["others_cpu"] is None
  assert machine.load_summary(samples[-2:], 2, 100)["others_cpu"] is None
  assert machine.load_summary([_sample(0.0, None, 5, 5)], 2, 100)["load"] is None


def test_busy_verdict_both_ways():
  # Others' share measured: it alone decides (a pinned neighbour on another core raises the
  # load, not the share of this run's cores).
  assert machine.verdict(0.1, 3.5, 2) == (False, None)
  busy, why = machine.verdict(0.6, 3.1, 2)
  assert busy and why == "others took 0.60 of each of 2 CPUs, load 3.1 on 2 CPUs"
  assert machine.verdict(machine.OTHERS_BUSY, 9.0, 2) == (False, None)  # at the line: not busy
  # Unmeasured: the mean load against the run's CPUs and the margin.
  assert machine.verdict(None, 3.1, 2) == (True, "load 3.1 on 2 CPUs")
  assert machine.verdict(None, 2.0 + machine.LOAD_MARGIN, 2) == (False, None)
  assert machine.verdict(None, None, 2) == (False, None)
  # The verdict of samples: others took 0.6 of each CPU, then none.
  for others, expected in ((600, True), (0, False)):
    samples = [_sample(0.0, 1.0, 0, 0), _sample(5.0, 1.0, 1000 + others, 1000)]
    summary = machine.load_summary(samples, 2, 100)
    assert machine.verdict(summary["others_cpu"]["mean"], 1.0, 2)[0] is expected


def test_busy_note_of_a_record():
  assert machine.busy_note({"busy": True, "busy_why": "load 3.1 on 2 CPUs"}) == (
      " (busy: load 3.1 on 2 CPUs)")
  assert machine.busy_note({"busy": False, "busy_why": None}) == ""
  assert machine.busy_note(None) == "" and machine.busy_note({"backend": "cpu"}) == ""


def test_rates():
  assert machine.rates(200, 1024, 4.0) == {"steps_per_second": 50.0,
                                           "rays_per_second": 51200.0}
  assert machine.rates(3, 256, 0.5)["rays_per_second"] == pytest.approx(1536.0)
  with pytest.raises(ValueError, match="positive"):
    machine.rates(10, 256, 0.0)


def test_metrics_json_holds_the_machine_beside_its_fields(trained_run):
  workdir, result = trained_run  # conftest's shared run, read only
  stored = json.loads((workdir / "metrics.json").read_text())
  assert {"psnr", "ssim", "per_view", "steps", "train_seconds", "background"} <= set(stored)
  assert stored["per_view"] == result["per_view"] and "machine" not in result
  _check_record(stored["machine"])
  # The load over the run: sampled from its start to its last step.
  assert stored["machine"]["seconds"] >= 0.8 * stored["train_seconds"]


def test_metrics_json_machine_carries_the_runs_rates(trained_run):
  workdir, _ = trained_run
  stored = json.loads((workdir / "metrics.json").read_text())
  config = json.loads((workdir / "config.json").read_text())
  expected = machine.rates(stored["steps"], config["train"]["batch_rays"],
                           stored["train_seconds"])
  # train_seconds is rounded to ms in metrics.json: the rates agree to that.
  for name, value in expected.items():
    assert stored["machine"][name] == pytest.approx(value, rel=1e-3)
