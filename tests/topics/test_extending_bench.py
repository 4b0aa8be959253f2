"""docs/extending.md's benchmark walk-through, run as written: its module is written into a
temporary folder and imported as the bench's module startup would be, its command runs from the
command line, the doc's test for it runs, and the index of nerf_jax/bench/__init__.py with the
doc's line added names every module of the folder once, the new one too (as
tests/bench/test_index.py checks the index); a new benchmark is two new files and that one
edit. No file of the tree is touched."""

import inspect
import json
import os
import pathlib
import re
import subprocess
import sys

import pytest

from nerf_jax import bench
from tests import helpers

THIS = "tests/topics/test_extending_bench.py"
NAME = "nerf_jax.bench.startup"
INDEX_LINE = re.compile(r"^(\w+\.py) +\S", re.MULTILINE)  # tests/bench/test_index.py's


def _section():
  with open(os.path.join(helpers.ROOT, "docs/extending.md")) as f:
    text = f.read()
  return text[text.index("## Adding a benchmark"):]


def _index_line():
  """The doc's ```text block marked 'index': the module's line in the index."""
  return helpers.doc_block("docs/extending.md", THIS, "index", "text").rstrip("\n")


@pytest.fixture
def startup(tmp_path, monkeypatch):
  """(the doc's module imported as nerf_jax.bench.startup, its file)."""
  return helpers.import_doc_module(tmp_path, monkeypatch, THIS, NAME, bench)


def test_a_benchmark_is_two_new_files_and_one_edit():
  blocks = re.findall(r"<!-- " + re.escape(THIS) + r": (\w+) -->", _section())
  assert blocks == ["module", "test", "index"]  # the module, its test, its index line
  here = pathlib.Path(bench.__file__).parent
  assert not (here / "startup.py").exists()  # the walk-through's module is new
  assert "startup.py" not in INDEX_LINE.findall(bench.__doc__)


def test_the_index_with_the_docs_line_names_every_module_once(startup):
  _, path = startup
  line = _index_line()
  assert "\n" not in line and INDEX_LINE.findall(line) == [path.name]
  heading = "Speed and cost of one part:\n"
  assert heading in bench.__doc__  # where the doc says the line goes
  index = bench.__doc__.replace(heading, heading + line + "\n")
  modules = sorted([p.name for p in pathlib.Path(bench.__file__).parent.glob("*.py")
                    if p.name != "__init__.py"] + [path.name])
  assert sorted(INDEX_LINE.findall(index)) == modules


def test_the_docs_test_of_the_benchmark_passes(startup, tmp_path):
  namespace = {"__name__": "test_startup"}
  exec(compile(helpers.doc_block("docs/extending.md", THIS, "test"), "test_startup.py",
               "exec"), namespace)  # pylint: disable=exec-used
  tests = [f for name, f in namespace.items() if name.startswith("test_")]
  assert len(tests) == 1 and list(inspect.signature(tests[0]).parameters) == ["tmp_path"]
  tests[0](tmp_path)


def test_a_failing_start_names_its_log_and_records_nothing(startup, tmp_path, monkeypatch):
  module, _ = startup
  monkeypatch.setattr(module, "CODE", "raise SystemExit(3)")
  log = str(tmp_path / "start.log")
  with pytest.raises(RuntimeError, match=f"status 3: see {re.escape(log)}"):
    module.start_seconds(2, log)
  assert os.path.isfile(log)  # the failed start's output, to read


@pytest.mark.slow  # a process that starts two more
def test_the_docs_command_runs_from_the_command_line(startup, tmp_path):
  _, path = startup
  out = tmp_path / "startup.jsonl"
  result = subprocess.run([sys.executable, str(path), "--repeats=1", f"--out={out}"],
                          capture_output=True, text=True, cwd=helpers.ROOT, check=False,
                          env={**os.environ, "PYTHONPATH": helpers.ROOT})
  assert result.returncode == 0, result.stderr
  record, = [json.loads(line) for line in out.read_text().splitlines()]
  assert record["command"] == f"{path} --repeats=1 --out={out}"
  assert f"start: {record['median_seconds']:.2f} s, the median of 1" in result.stdout
  bad = subprocess.run([sys.executable, str(path), "--repeats=0"], capture_output=True,
                       text=True, cwd=helpers.ROOT, check=False,
                       env={**os.environ, "PYTHONPATH": helpers.ROOT})
  assert bad.returncode == 1 and "repeats" in bad.stderr and "Traceback" not in bad.stderr
