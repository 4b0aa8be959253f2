"""The benchmark's instruments: a pausable training clock, timed calls and compiles, the
machine's matmul peak, MLP FLOPs, memory, and the machine the numbers belong to.

Time words:
  train seconds: wall clock from the start of compiling the train step to the end of the last
    step, with the clock paused during PSNR probes; compile time is inside it.
  probe: PSNR on a few test views, taken at a host sync, with the clock paused.
"""

import contextlib
import os
import resource
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.run import machine

MATMUL_SHAPES = ((4096, 256, 256), (16384, 64, 64), (1024, 1024, 1024))  # (M, K, N)


class Clock:
  """Training seconds: runs from start(), stands still while `paused()`."""

  def __init__(self):
    self._total, self._since = 0.0, None

  def start(self):
    self._since = time.perf_counter()

  def seconds(self):
    running = 0.0 if self._since is None else time.perf_counter() - self._since
    return self._total + running

  def stop(self):
    self._total, self._since = self.seconds(), None
    return self._total

  @contextlib.contextmanager
  def paused(self):
    self.stop()
    try:
      yield
    finally:
      self.start()


def compile_jitted(jitted, *args):
  """(executable, seconds to trace, lower and compile `jitted` for `args`); runs nothing."""
  start = time.perf_counter()
  compiled = jitted.lower(*args).compile()
  return compiled, time.perf_counter() - start


def sample_seconds(fn, repeats, warmup=1):
  """Wall seconds of `repeats` calls of `fn` (which must block) after `warmup` untimed calls."""
  for _ in range(warmup):
    fn()
  times = []
  for _ in range(repeats):
    start = time.perf_counter()
    fn()
    times.append(time.perf_counter() - start)
  return times


def median_step_seconds(segments):
  """Median over segments of seconds per step. segments: [(steps, seconds)]."""
  return float(np.median([seconds / steps for steps, seconds in segments]))


def psnr_at_times(probes, times):
  """PSNR reached by each time: that of the latest probe at or before it (None before any).

  probes: [{'seconds': float, 'psnr': float, ...}] in any order. times: [float] train seconds.
  """
  ordered = sorted(probes, key=lambda p: p["seconds"])
  out = []
  for t in times:
    before = [p["psnr"] for p in ordered if p["seconds"] <= t]
    out.append(before[-1] if before else None)
  return out


def matmul_gflops(dtype="float32", shapes=MATMUL_SHAPES, repeats=10):
  """This machine's dense matmul throughput: {'MxKxN': GFLOP/s}, median of `repeats`."""
  key_a, key_b = jax.random.split(jax.random.PRNGKey(0))
  result = {}
  for m, k, n in shapes:
    a = jax.random.normal(key_a, (m, k)).astype(dtype)
    b = jax.random.normal(key_b, (k, n)).astype(dtype)
    matmul, _ = compile_jitted(jax.jit(jnp.matmul), a, b)
    times = sample_seconds(lambda: matmul(a, b).block_until_ready(), repeats)
    result[f"{m}x{k}x{n}"] = 2.0 * m * k * n / float(np.median(times)) / 1e9
  return result


def mlp_flops_per_sample(net_params):
  """Forward FLOPs of one MLP evaluation: 2·in·out per Dense kernel [in, out] (biases ignored)."""
  leaves = jax.tree_util.tree_flatten_with_path(net_params)[0]
  return sum(2 * x.shape[0] * x.shape[1] for path, x in leaves
             if getattr(path[-1], "key", None) == "kernel")


def mlp_flops_per_step(params, config, rays_per_step):
  """MLP FLOPs of one train step: forward + backward ≈ 3 × forward, over every sample."""
  flops = mlp_flops_per_sample(params["coarse"]) * config.num_samples
  if config.num_fine_samples > 0:
    fine = params["coarse" if config.model.shared_fine else "fine"]
    flops += mlp_flops_per_sample(fine) * (config.num_samples + config.num_fine_samples)
  return 3 * rays_per_step * flops


def peak_rss_mb():
  """Peak resident memory of this process so far, in MiB."""
  peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
  return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes on macOS, KiB else


def device_peak_mb():
  """Peak accelerator memory in MiB where the backend reports it (not on CPU), else None."""
  stats = jax.devices()[0].memory_stats() or {}
  peak = stats.get("peak_bytes_in_use")
  return None if peak is None else peak / 2**20


def machine_info():
  """The machine and software versions the numbers belong to (run/machine.py's `describe`),
  with flax's and optax's versions and the load average now."""
  import flax
  import optax
  return {**machine.describe(), "flax": flax.__version__, "optax": optax.__version__,
          "load_average": [round(x, 2) for x in os.getloadavg()]}
