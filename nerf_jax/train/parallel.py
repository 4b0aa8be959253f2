"""Data-parallel training with `jax.sharding`: one mesh axis 'data' over every device.

The training arrays and the parameters are replicated on every device; each step's ray batch is
split over the devices (`shard_batch`), so every device renders B / D rays and XLA all-reduces
the gradients. With one device everything here is a no-op. Several hosts (processes) join one
mesh through `jax.distributed.initialize` (see `initialize_distributed` and docs/usage.md); every
process runs the same steps, so whatever decides a step (the start state, when to stop) must be
the same in all of them.
"""

import os

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

AXIS = "data"


def initialize_distributed():
  """Join a multi-process run when its environment says so; returns whether it did.

  JAX_COORDINATOR_ADDRESS (host:port of process 0) with JAX_NUM_PROCESSES and JAX_PROCESS_ID
  start it explicitly; under SLURM or Open MPI with more than one task JAX reads them itself.
  Must run before anything touches a device. CPU processes exchange gradients through Gloo,
  jax's default CPU collectives (config jax_cpu_collectives_implementation), so nothing else is
  needed to try it on one machine.
  """
  if os.environ.get("JAX_COORDINATOR_ADDRESS"):
    num = os.environ.get("JAX_NUM_PROCESSES")
    pid = os.environ.get("JAX_PROCESS_ID")
    jax.distributed.initialize(num_processes=int(num) if num else None,
                               process_id=int(pid) if pid else None)
    return True
  tasks = os.environ.get("SLURM_NTASKS") or os.environ.get("OMPI_COMM_WORLD_SIZE") or "1"
  if int(tasks) > 1:
    jax.distributed.initialize()
    return True
  return False


def make_mesh(enabled=True):
  """A 1-D Mesh over all (global) devices, or None when disabled or there is only one."""
  devices = jax.devices()
  if not enabled or len(devices) == 1:
    return None
  return Mesh(np.asarray(devices), (AXIS,))


def replicate(tree, mesh):
  """Put every array of `tree` on all devices of `mesh` (unchanged when mesh is None)."""
  if mesh is None:
    return tree
  sharding = NamedSharding(mesh, P())

  def put(x):
    x = np.asarray(x)
    # Every process passes the same value; make_array_from_callback also works across hosts.
    return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])

  return jax.tree_util.tree_map(put, tree)


def shard_batch(tree, mesh):
  """Constrain (inside jit) the leading axis of every array of `tree` to be split over 'data'."""
  if mesh is None:
    return tree
  sharding = NamedSharding(mesh, P(AXIS))
  return jax.tree_util.tree_map(lambda x: jax.lax.with_sharding_constraint(x, sharding), tree)


def replicated_constraint(tree, mesh):
  """Constrain (inside jit) every array of `tree` to be replicated over the mesh."""
  if mesh is None:
    return tree
  sharding = NamedSharding(mesh, P())
  return jax.tree_util.tree_map(lambda x: jax.lax.with_sharding_constraint(x, sharding), tree)


def to_host(tree):
  """numpy copy of a pytree of (possibly replicated, multi-host) arrays."""
  def get(x):
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
      x = x.addressable_shards[0].data  # replicated: any local copy is the whole value
    return np.asarray(x)
  return jax.tree_util.tree_map(get, tree)


def from_main(tree):
  """Process 0's values of a pytree of host arrays (same shapes in every process), on every
  process; `tree` itself with one process. For what only process 0 reads (the workdir)."""
  if jax.process_count() == 1:
    return tree
  return multihost_utils.broadcast_one_to_all(tree)


def is_main_process():
  """Process 0 writes checkpoints, logs and images; the others only compute."""
  return jax.process_index() == 0


def check_batch(rays_per_step, mesh):
  """A ValueError unless `rays_per_step` splits evenly over the mesh's devices."""
  if mesh is not None and rays_per_step % mesh.size:
    raise ValueError(f"config.train.batch_rays: {rays_per_step} rays per step do not split over "
                     f"{mesh.size} devices; use a multiple of {mesh.size} or set "
                     "config.train.data_parallel=False")


def check_time_budget(max_seconds):
  """A ValueError for a time budget (train.max_seconds > 0) with several processes: each
  process's clock would end its calibration and its run at a different step, and the
  collectives of the others would then wait for ever."""
  if max_seconds > 0 and jax.process_count() > 1:
    raise ValueError(f"config.train.max_seconds: a time budget needs one process, this run has "
                     f"{jax.process_count()}; set config.train.max_steps and "
                     "config.train.max_seconds=0")
