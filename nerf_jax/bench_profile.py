"""Where a train step's time goes: each stage of the step timed alone, side by side.

  python -m nerf_jax.bench_profile                          # configs/default.py
  python -m nerf_jax.bench_profile --config=fast --batch_rays=2048

Stages (each jitted on its own, median of --repeats calls after a warm-up): the whole train step;
drawing the batch; sampling + encoding (forward only: nothing upstream needs a gradient); the
field's forward + backward on pre-encoded inputs; compositing forward + backward; and plain
matmuls with the MLP's shapes, [rays·samples, in] × [in, out], forward only. The
stages do not add up exactly (XLA fuses across them in the real step), but they show which one
dominates and how far the MLP (fwd + bwd ≈ 3 × the forward FLOPs) is from the matmul speed of
its own shapes and from the large-square matmul peak.
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax import bench, bench_sweeps, encoding, rendering, renderer, sampling, train_lib
from nerf_jax.data import loaders
from nerf_jax.model import make_model


def median_ms(fn, *args, repeats=10):
  """Median wall milliseconds of fn(*args) (jitted, blocking), compilation excluded."""
  compiled = jax.jit(fn).lower(*args).compile()
  run = lambda: jax.block_until_ready(compiled(*args))
  return 1e3 * float(np.median(bench.sample_seconds(run, repeats)))


def _kernels(params):
  leaves = jax.tree_util.tree_flatten_with_path(params)[0]
  return [x for path, x in leaves if getattr(path[-1], "key", None) == "kernel"]


def profile(config, repeats=10):
  """[(stage, ms, note)] for one train step of `config` on its dataset."""
  train_ds, _ = loaders.load_dataset(config.data)
  near, far = train_lib.bounds(config, train_ds)
  model = make_model(config.model)
  tx = train_lib.make_optimizer(config.train)
  state = train_lib.init_state(model, tx, config)
  data = train_lib.make_train_data(train_ds, config)
  key = jax.random.PRNGKey(0)
  rays, samples = config.train.batch_rays, config.num_samples
  step = train_lib.make_train_step(model, tx, config, near, far)
  compiled = step.lower(state, data, key).compile()
  times = []
  for _ in range(repeats + 1):
    start = time.perf_counter()
    state, stats = compiled(state, data, key)
    jax.block_until_ready(stats)
    times.append(time.perf_counter() - start)
  rows = [("train step (all)", 1e3 * float(np.median(times[1:])), f"{rays} rays × {samples}")]

  batch = train_lib.draw_batch(data, config, key)
  rows.append(("draw batch (gathers)", median_ms(
      lambda k: train_lib.draw_batch(data, config, k), key, repeats=repeats), ""))
  grid_model = config.model.get("encoding", "posenc") == "grid"

  def sample_encode(o, d, k):
    t = sampling.stratified(near, far, samples, o.shape[:-1], k)
    points = o[..., None, :] + d[..., None, :] * sampling.midpoints(t)[..., None]
    return points if grid_model else encoding.positional_encoding(points, config.pos_encode_dims)
  features = sample_encode(batch.origins, batch.directions, key)
  rows.append(("sample + encode (fwd)", median_ms(sample_encode, batch.origins, batch.directions,
                                                  key, repeats=repeats), f"{features.shape}"))

  params = state.params["coarse"]
  dirs = None
  if config.model.view_dependent:
    dirs = jnp.zeros((*features.shape[:-1], encoding.encoded_width(3, config.dir_encode_dims)))
  field = lambda p, x: jnp.sum(sum(jnp.sum(o) for o in model.apply({"params": p}, x, dirs)))
  rows.append(("field fwd+bwd", median_ms(jax.grad(field), params, features, repeats=repeats),
               f"{len(_kernels(params))} dense layers"))

  rgb = jnp.full((rays, samples, 3), 0.5)
  sigma = jnp.ones((rays, samples))
  t = jnp.broadcast_to(jnp.linspace(near, far, samples + 1), (rays, samples + 1))
  composite = lambda c, s: jnp.sum(rendering.composite(c, s, t)["rgb"])
  rows.append(("composite fwd+bwd", median_ms(jax.grad(composite, argnums=(0, 1)), rgb, sigma,
                                               repeats=repeats), ""))

  n = rays * samples
  kernels = _kernels(params)
  inputs = [jnp.ones((n, k.shape[0])) for k in kernels]
  flops = sum(2 * n * k.shape[0] * k.shape[1] for k in kernels)
  ms = median_ms(lambda xs, ks: [x @ k for x, k in zip(xs, ks)], inputs, kernels,
                 repeats=repeats)
  rows.append(("the MLP's matmuls alone (fwd)", ms, f"{flops / ms / 1e6:.1f} GFLOP/s at its "
               "shapes"))
  field_ms = rows[3][1]
  rows[3] = (*rows[3][:2], f"{rows[3][2]}, {3 * flops / field_ms / 1e6:.1f} GFLOP/s")
  peak = max(bench.matmul_gflops(repeats=repeats).values())
  rows.append(("dense matmul peak", float("nan"), f"{peak:.1f} GFLOP/s (large square)"))
  return rows


def main(argv=None):
  parser = argparse.ArgumentParser(prog="python -m nerf_jax.bench_profile",
                                   description=__doc__.split("\n\n")[0])
  parser.add_argument("--config", default="default", help="config name under configs/ or path")
  parser.add_argument("--batch_rays", type=int, default=0, help="rays per step (0 = config's)")
  parser.add_argument("--repeats", type=int, default=10, help="timed calls per stage")
  args = parser.parse_args(argv)
  config = bench_sweeps.load_base(args.config)
  if args.batch_rays:
    config.train.batch_rays = args.batch_rays
  print(f"{args.config}: {jax.devices()[0].device_kind}, jax {jax.__version__}")
  print("| stage | median ms | note |\n|---|---|---|")
  for stage, ms, note in profile(config, args.repeats):
    print(f"| {stage} | {'' if np.isnan(ms) else f'{ms:.1f}'} | {note} |")


if __name__ == "__main__":
  main()
