"""bench/records.py: the stamp every benchmark record carries (date, git, run/machine.py's
record), JSON-lines files written and read back, old records read as they are, a broken line
named; and the stamp on the records of the writers whose own tests do not run them (capture's
record.json, the regret table's summary.jsonl, the standard rows' scoring fields)."""

import datetime
import glob
import json
import os
import re

import pytest

from nerf_jax.bench import capture, records, regret, regret_table
from nerf_jax.data.dataset import DataError
from nerf_jax.run import machine
from tests.helpers import ROOT

GIT = re.compile(r"[0-9a-f]{40}(-dirty)?")  # a commit, '-dirty' where files differ from it


def assert_stamped(record, measured=None):
  """`record` carries records.STAMP: a UTC date of the last minutes, the checkout's commit, and
  the machine record `measured` (where given), else one describing this machine."""
  written = datetime.datetime.strptime(record["date"], records.DATE_FORMAT).replace(
      tzinfo=datetime.timezone.utc)
  age = datetime.datetime.now(datetime.timezone.utc) - written
  assert datetime.timedelta(0) <= age < datetime.timedelta(minutes=30)
  assert record["git"] is None or GIT.fullmatch(record["git"]), record["git"]
  if measured is not None:
    assert record["machine"] == measured
  else:
    assert record["machine"]["cpu_count"] == os.cpu_count() and record["machine"]["backend"]


def test_the_stamp_holds_the_date_the_code_and_the_measured_machine(monkeypatch):
  monkeypatch.setattr(machine, "git_revision", lambda: "c" * 40)
  sampler = machine.Sampler(every=0.01)
  measured = sampler.stop()
  record = records.stamp({"psnr": 20.0, "machine": "an old line"}, measured)
  assert record["psnr"] == 20.0 and record["git"] == "c" * 40
  assert record["machine"] is measured  # the Sampler's: what the machine is, and its load
  for field in ("cpu_model", "cpu_count", "backend", "jax", "load", "others_cpu", "busy"):
    assert field in measured
  assert_stamped(record, measured)
  # Without one measured: the record's own machine record, else what describe() says.
  own = {"backend": "cpu", "busy": True}
  assert records.stamp({"machine": own})["machine"] is own
  described = records.stamp({"psnr": 1.0})["machine"]
  assert described == machine.describe()
  assert set(records.STAMP) <= set(records.stamp({}))


def test_append_and_write_round_trip_and_read_skips_blank_lines(tmp_path):
  path = str(tmp_path / "new" / "results.jsonl")
  assert records.read(path) == []  # no file yet
  first, second = {"a": 1, "nested": {"b": [1.5, None]}}, {"a": 2, "text": "é"}
  records.append(path, first)
  records.append(path, second)
  assert records.read(path) == [first, second]
  with open(path) as f:
    assert [json.loads(line) for line in f] == [first, second]  # one record a line
  with open(path, "a") as f:
    f.write("\n  \n")
  assert records.read(path) == [first, second]
  records.write(path, [second])
  assert records.read(path) == [second]


def test_a_broken_line_is_one_line_naming_the_file_and_line(tmp_path):
  path = tmp_path / "results.jsonl"
  path.write_text('{"a": 1}\n{"a": 2, "trunc\n')
  with pytest.raises(DataError, match=r"results.jsonl:2: not a JSON record"):
    records.read(str(path))
  path.write_text('{"a": 1}\n[1, 2]\n')
  with pytest.raises(DataError, match=r"results.jsonl:2: not a JSON object"):
    records.read(str(path))
  with pytest.raises(TypeError):  # not JSON: nothing written
    records.append(str(path), {"a": object()})
  assert path.read_text() == '{"a": 1}\n[1, 2]\n'


def test_every_committed_jsonl_record_still_reads():
  paths = glob.glob(os.path.join(ROOT, "docs", "bench", "**", "*.jsonl"), recursive=True)
  assert len(paths) > 10
  for path in paths:
    rows = records.read(path)
    with open(path) as f:
      assert len(rows) == sum(1 for line in f if line.strip()), path


def test_captures_record_is_stamped_with_the_machine_its_sfm_run_measured(tmp_path):
  measured = {"cpu_count": 2, "backend": "cpu", "busy": False}
  assert capture._run_machine(str(tmp_path)) is None  # nothing trained
  (tmp_path / "train_sfm").mkdir()
  (tmp_path / "train_sfm" / "metrics.json").write_text(json.dumps({"machine": measured}))
  assert capture._run_machine(str(tmp_path)) == measured
  assert_stamped(records.stamp({"views": 40}, capture._run_machine(str(tmp_path))), measured)


def test_the_regret_tables_rows_are_stamped_with_autos_machine(tmp_path):
  auto_machine = {"backend": "cpu", "cpu_count": 2, "busy": False}
  rows, value = regret.with_regret([
      {"scene": "fog", "run": "auto", "flipped": "", "base": "fast", "overrides": {},
       "psnr": 20.0, "steps": 10, "seconds": 6.0, "seconds_per_step": 0.1,
       "machine": auto_machine},
      {"scene": "fog", "run": "flip/background", "flipped": "background", "base": "fast",
       "overrides": {"train.random_background": False}, "error": "boom"}])
  regret.write_results(rows, value, str(tmp_path / "fog"), "cmd")
  summary, = regret_table.summarize(str(tmp_path))
  assert_stamped(summary, auto_machine)
  assert records.read(str(tmp_path / "summary.jsonl")) == [summary]
