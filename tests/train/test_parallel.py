"""Data-parallel training over 4 CPU devices, and over 2 processes joined by jax.distributed,
matches the single-device run.

The device count must be fixed before JAX starts, so the 4-device run is a subprocess with
XLA_FLAGS=--xla_force_host_platform_device_count=4; the two processes are two `train.py` runs
(cli.train_main) on localhost, one CPU device each.
"""

import json
import os
import socket
import subprocess
import sys
import time
import types

import jax
import numpy as np
import pytest

from nerf_jax.run import experiment
from nerf_jax.run.signature import init_state, model_signature
from nerf_jax.train import checkpoints, parallel
from nerf_jax.run import train_lib
from tests.helpers import restored_variables
from tests.helpers import small_config

from tests.helpers import ROOT
STEPS = 10

SCRIPT = r"""
import json, sys
import jax
import numpy as np
from nerf_jax.configs import debug
from nerf_jax.run import builders, experiment
from nerf_jax.run.signature import init_state
from nerf_jax.train import parallel

config = debug.get_config()
exp = experiment.setup(config)
data = builders.make_train_data(exp)
key = jax.random.PRNGKey(1)

def run(mesh):
  state = parallel.replicate(init_state(exp), mesh)
  replicated = parallel.replicate(data, mesh)
  step = builders.make_train_step(exp, mesh)
  hlo = step.lower(state, replicated, key).compile().as_text()
  losses = []
  for _ in range(STEPS):
    state, stats = step(state, replicated, key)
    losses.append(float(stats["loss"]))
  return state, losses, hlo

single, single_losses, _ = run(None)
mesh = parallel.make_mesh()
multi, multi_losses, hlo = run(mesh)
leaves = jax.tree_util.tree_leaves
diff = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
           for a, b in zip(leaves(single.params), leaves(multi.params)))
kernel = leaves(multi.params)[0]
print(json.dumps({
    "devices": jax.device_count(), "mesh": None if mesh is None else mesh.size,
    "single": single_losses, "multi": multi_losses, "param_diff": diff,
    "all_reduce": "all-reduce" in hlo, "replicated": kernel.sharding.is_fully_replicated,
    "param_devices": len(kernel.sharding.device_set)}))
""".replace("STEPS", str(STEPS))


@pytest.mark.slow
def test_four_devices_match_one():
  env = dict(os.environ, PYTHONPATH=ROOT, XLA_FLAGS="--xla_force_host_platform_device_count=4",
             JAX_PLATFORMS="cpu")
  res = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=600)
  assert res.returncode == 0, res.stderr[-3000:]
  out = json.loads(res.stdout.strip().splitlines()[-1])
  assert out["devices"] == 4 and out["mesh"] == 4
  assert out["all_reduce"]  # the batch really is split: gradients are summed across devices
  assert out["replicated"] and out["param_devices"] == 4
  # Same batches, same keys; only the order of the floating-point reductions differs.
  assert out["single"] == pytest.approx(out["multi"], rel=1e-4)
  assert out["single"][-1] < out["single"][0]
  assert out["param_diff"] < 1e-4
  # The whole loop (train.py) over several devices: test_two_processes_match_one.


# Two processes of one CPU device each: train.py's own flags for configs/debug.py's 20 steps
# (tests.helpers.small_config()), and what each process reports at the end.
TWO_PROCESS_SCRIPT = r"""
import json, sys
import jax
from nerf_jax import cli
from nerf_jax.run import train_lib

results = []
train = train_lib.train_and_evaluate
train_lib.train_and_evaluate = (lambda *args, **kw: results.append(train(*args, **kw))
                                or results[-1])
try:
  cli.train_main(["train.py", *sys.argv[1:]])
except SystemExit as e:
  if e.code:
    raise
print(json.dumps({"process": jax.process_index(), "processes": jax.process_count(),
                  "devices": jax.device_count(), "psnr": results[0]["psnr"]}))
"""


def _free_port():
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    return s.getsockname()[1]


def _start_two_processes(workdirs, logs):
  """Popen two train runs joined through JAX_COORDINATOR_ADDRESS (parallel.initialize_distributed),
  process i in workdirs[i], its stdout and stderr into logs[i]."""
  port, procs = _free_port(), []
  for i in range(2):
    env = dict(os.environ, PYTHONPATH=ROOT, JAX_PLATFORMS="cpu", JAX_NUM_PROCESSES="2",
               JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}", JAX_PROCESS_ID=str(i))
    env.pop("XLA_FLAGS", None)  # one CPU device per process
    with open(logs[i], "w") as log:
      procs.append(subprocess.Popen(
          [sys.executable, "-c", TWO_PROCESS_SCRIPT, "--config=debug",
           "--config.render.after_training=False", f"--workdir={workdirs[i]}"],
          cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT))
  return procs


def _wait(procs, logs, timeout):
  """The last stdout line of each process, parsed; kills them all if one fails or hangs."""
  deadline = time.monotonic() + timeout
  try:
    for proc, log in zip(procs, logs):
      proc.wait(timeout=max(deadline - time.monotonic(), 1))
      assert proc.returncode == 0, open(log).read()[-3000:]
    return [json.loads(open(log).read().strip().splitlines()[-1]) for log in logs]
  finally:
    for proc in procs:
      if proc.poll() is None:
        proc.kill()
        proc.wait()


@pytest.mark.slow
def test_two_processes_match_one(tmp_path):
  # Both runs start from the same step-0 checkpoint of other parameters than config.seed's, which
  # only process 0's workdir holds: process 1 must take process 0's start state.
  config = small_config()
  exp = experiment.setup(config)
  state = init_state(exp)
  state = state.replace(params=exp.renderer.init(jax.random.PRNGKey(7))["params"])
  single_dir, workdirs = tmp_path / "single", [tmp_path / "p0", tmp_path / "p1"]
  for workdir in (single_dir, workdirs[0]):
    checkpoints.save(str(workdir), 0, jax.device_get(state), model_signature(config))
  logs = [tmp_path / "log0.txt", tmp_path / "log1.txt"]
  procs = _start_two_processes(workdirs, logs)
  try:
    single = train_lib.train_and_evaluate(config, str(single_dir))  # meanwhile, on one device
  finally:
    outs = _wait(procs, logs, timeout=300)
  assert [o["process"] for o in outs] == [0, 1]
  assert all(o["processes"] == 2 and o["devices"] == 2 for o in outs)
  # Only process 0 reads and writes a workdir: process 1 does not even create its own.
  assert not workdirs[1].exists()
  assert sorted(os.listdir(workdirs[0])) == sorted(os.listdir(single_dir))
  assert checkpoints.list_steps(str(workdirs[0])) == [10, 20]
  # Same global batch of 256 rays and same keys; only the order in which the two halves' gradient
  # sums are added may differ (float32 rounding, ~1e-7 relative), and Adam's step
  # lr·m/(√v + ε) hardly depends on the gradient's scale: far below 1e-6 after 20 steps of at
  # most lr = 5e-3 each (measured: 0, bit for bit), while every tensor moves by > 1e-3.
  leaves = jax.tree_util.tree_leaves
  for multi, one, start in zip(leaves(restored_variables(workdirs[0])["params"]),
                               leaves(restored_variables(single_dir)["params"]),
                               leaves(state.params)):
    np.testing.assert_allclose(multi, one, rtol=0, atol=1e-6)
    assert np.max(np.abs(one - np.asarray(start))) > 1e-3
  # Process 1 evaluated its own copy of the parameters: the same ones.
  assert outs[1]["psnr"] == outs[0]["psnr"] == pytest.approx(single["psnr"], abs=1e-4)
  final = json.loads(open(workdirs[0] / "metrics.jsonl").read().splitlines()[-1])
  assert final["final"] and final["eval_psnr"] == outs[0]["psnr"]


def test_one_device_or_disabled_is_a_no_op():
  assert parallel.make_mesh(enabled=False) is None
  tree = {"a": [1.0, 2.0]}
  assert parallel.replicate(tree, None) is tree
  assert parallel.shard_batch(tree, None) is tree


def test_a_batch_that_does_not_split_is_refused():
  mesh = types.SimpleNamespace(size=4)
  parallel.check_batch(256, mesh)
  with pytest.raises(ValueError, match="batch_rays: 255 rays .* 4 devices"):
    parallel.check_batch(255, mesh)


def test_a_time_budget_is_refused_with_several_processes(monkeypatch):
  parallel.check_time_budget(5.0)  # one process: fine
  monkeypatch.setattr(jax, "process_count", lambda: 2)
  with pytest.raises(ValueError, match="max_seconds: a time budget needs one process"):
    parallel.check_time_budget(5.0)
  parallel.check_time_budget(0.0)  # a step budget: fine


def test_no_distributed_environment_means_one_process(monkeypatch):
  for name in ("JAX_COORDINATOR_ADDRESS", "SLURM_NTASKS", "OMPI_COMM_WORLD_SIZE"):
    monkeypatch.delenv(name, raising=False)
  assert parallel.initialize_distributed() is False
