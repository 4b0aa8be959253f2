"""Data-parallel training over 4 CPU devices matches the single-device run.

The device count must be fixed before JAX starts, so the 4-device run is a subprocess with
XLA_FLAGS=--xla_force_host_platform_device_count=4.
"""

import json
import os
import subprocess
import sys
import types

import pytest

from nerf_jax import parallel, train_lib
from tests.conftest import tiny_config

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STEPS = 10

SCRIPT = r"""
import json, sys
import jax
import numpy as np
from nerf_jax.configs import debug
from nerf_jax import experiment, parallel, train_lib

config = debug.get_config()
config.render.after_training = False
exp = experiment.setup(config)
data = train_lib.make_train_data(exp)
key = jax.random.PRNGKey(1)

def run(mesh):
  state = parallel.replicate(experiment.init_state(exp), mesh)
  replicated = parallel.replicate(data, mesh)
  step = train_lib.make_train_step(exp, mesh)
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
result = train_lib.train_and_evaluate(config, sys.argv[1])  # the whole loop on 4 devices
print(json.dumps({
    "devices": jax.device_count(), "mesh": None if mesh is None else mesh.size,
    "single": single_losses, "multi": multi_losses, "param_diff": diff,
    "all_reduce": "all-reduce" in hlo, "replicated": kernel.sharding.is_fully_replicated,
    "param_devices": len(kernel.sharding.device_set), "psnr": result["psnr"],
    "steps": result["steps"]}))
""".replace("STEPS", str(STEPS))


@pytest.mark.slow
def test_four_devices_match_one(tmp_path):
  env = dict(os.environ, PYTHONPATH=ROOT, XLA_FLAGS="--xla_force_host_platform_device_count=4",
             JAX_PLATFORMS="cpu")
  res = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "run")], cwd=ROOT, env=env,
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
  # The whole loop on 4 devices scores what the same loop on one device scores (20 steps learn
  # little: the quality bar against trivial answers is test_quality.py's, on the shared run).
  config = tiny_config()
  single = train_lib.train_and_evaluate(config, str(tmp_path / "single"))
  assert out["steps"] == 20 and out["psnr"] == pytest.approx(single["psnr"], abs=0.02)
  assert os.path.exists(tmp_path / "run" / "checkpoints" / "ckpt_20.msgpack")


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


def test_no_distributed_environment_means_one_process(monkeypatch):
  for name in ("JAX_COORDINATOR_ADDRESS", "SLURM_NTASKS", "OMPI_COMM_WORLD_SIZE"):
    monkeypatch.delenv(name, raising=False)
  assert parallel.initialize_distributed() is False
