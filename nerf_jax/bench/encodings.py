"""What a grid encoding costs per training step on this machine, side by side: the dense levels
(grid.py) and TensoRF's vector-matrix fields (tensorf.py) at several sizes.

  python -m nerf_jax.bench.encodings            # 131,072 samples: a 4096 x 32 step
  python -m nerf_jax.bench.encodings --samples=65536 --repeats=5

For each, the median milliseconds of the forward read of `samples` random positions, and of
the forward + backward + an Adam update of the tables (what a train step spends on them).
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np
import optax

from nerf_jax.fields.encodings import grid, tensorf
from nerf_jax.bench import measure

# (label, kind, level resolutions, features per point or rank)
CANDIDATES = (
    ("dense (32,64,128) x 4", "dense", (32, 64, 128), 4),
    ("dense (64,128,256) x 2", "dense", (64, 128, 256), 2),
    ("tensorf (256,) rank 16", "tensorf", (256,), 16),
    ("tensorf (128,256) rank 8", "tensorf", (128, 256), 8),
    ("tensorf (128,256) rank 16", "tensorf", (128, 256), 16),
    ("tensorf (512,) rank 16", "tensorf", (512,), 16),
)


def tables(kind, resolutions, width, key):
  """{name: float32 table} of one candidate, 0.1·N(0, 1)."""
  shapes = {}
  for r in resolutions:
    if kind == "dense":
      shapes[f"grid_{r}"] = (r, r, r, width)
    else:
      planes, lines = tensorf.shapes((r, r, r), width)
      shapes.update({f"plane_{r}_{m}": s for m, s in enumerate(planes)})
      shapes.update({f"line_{r}_{m}": s for m, s in enumerate(lines)})
  keys = jax.random.split(key, len(shapes))
  return {n: 0.1 * jax.random.normal(k, s) for k, (n, s) in zip(keys, shapes.items())}


def encoder(kind, resolutions):
  """features(tables, unit float32 [N, 3]) -> float32 [N, F] of one candidate."""
  if kind == "dense":
    return lambda t, unit: grid.multires_features([t[f"grid_{r}"] for r in resolutions], unit)
  return lambda t, unit: jnp.concatenate([tensorf.vm_features(
      [t[f"plane_{r}_{m}"] for m in range(3)], [t[f"line_{r}_{m}"] for m in range(3)], unit)
      for r in resolutions], axis=-1)


def measure_one(kind, resolutions, width, samples, repeats):
  """(parameters, forward ms, forward + backward + Adam ms) of one candidate."""
  key = jax.random.PRNGKey(0)
  params = tables(kind, resolutions, width, key)
  unit = jax.random.uniform(key, (samples, 3))
  encode = encoder(kind, resolutions)
  tx = optax.adam(1e-2)

  def step(params, opt_state, unit):
    grads = jax.grad(lambda p: jnp.sum(encode(p, unit) ** 2))(params)
    updates, opt_state = tx.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state

  def median_ms(fn, *args):  # the untimed warm-up call compiles
    return 1e3 * float(np.median(measure.sample_seconds(
        lambda: jax.block_until_ready(fn(*args)), repeats)))

  count = sum(int(x.size) for x in params.values())
  return (count, median_ms(jax.jit(encode), params, unit),
          median_ms(jax.jit(step), params, tx.init(params), unit))


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--samples", type=int, default=131072, help="positions per read")
  parser.add_argument("--repeats", type=int, default=7, help="timed calls per measurement")
  args = parser.parse_args()
  print(f"{'encoding':28s} {'params':>8s} {'fwd ms':>8s} {'fwd+bwd+adam ms':>16s}")
  for label, kind, resolutions, width in CANDIDATES:
    count, forward, step = measure_one(kind, resolutions, width, args.samples, args.repeats)
    print(f"{label:28s} {count / 1e6:7.2f}M {forward:8.1f} {step:16.1f}", flush=True)


if __name__ == "__main__":
  main()
