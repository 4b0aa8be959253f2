"""nerf_jax.bench.check, the end-to-end machine check: its rows come from real runs and a real
pytest, and its table shows what they measured."""

import json

import pytest

from nerf_jax.bench import check


@pytest.mark.slow  # a training and a pytest, each in its own process
def test_rows_read_a_real_run_and_a_real_suite(tmp_path):
  row = check.train_row("tiny", "debug", {"train.max_steps": 6, "render.video_frames": 0},
                        str(tmp_path), timeout=300)
  metrics = json.loads((tmp_path / "tiny" / "metrics.json").read_text())
  assert row["status"] == "ok" and row["steps"] == 6 == metrics["steps"]
  assert row["psnr"] == metrics["psnr"] > 5.0
  assert row["steps_per_s"] == pytest.approx(6 / metrics["train_seconds"])
  # A suite of one passing and one failing test is counted as such, with pytest's exit code.
  tests = tmp_path / "suite"
  tests.mkdir()
  (tests / "test_two.py").write_text("def test_ok():\n  assert True\n\n"
                                     "def test_bad():\n  assert False\n")
  suite = check.suite_row(str(tmp_path), str(tests), "0", timeout=120)
  assert suite["status"] == "1 failed, 1 passed (exit 1)"
  text = check.table([row, suite], "cpu | cpu | 0.10.2")
  assert "cpu | cpu | 0.10.2" in text
  assert f"| tiny | debug | 6 | {row['steps_per_s']:.1f} | {row['psnr']:.2f} |" in text
  assert "| quick suite | - | - | - | - |" in text


@pytest.mark.slow  # a process that fails
def test_a_failed_stage_is_a_row_not_a_crash(tmp_path):
  row = check.train_row("bad", "debug", {"data.path": str(tmp_path / "missing")},
                        str(tmp_path), timeout=120)
  assert row["status"] == "exit 1" and "psnr" not in row
  assert "no such" in (tmp_path / "bad.log").read_text().lower()
  assert "| bad | debug | - | - | - |" in check.table([row], "cpu")
