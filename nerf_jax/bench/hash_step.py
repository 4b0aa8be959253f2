"""Train-step time of the dense grids (configs/fast.py) beside hash grids of several table sizes.

  python -m nerf_jax.bench.hash_step                                 # log2 sizes 14 16 17 18 19
  python -m nerf_jax.bench.hash_step--log2_sizes=15,19 --steps=20 --float16

Every variant is compiled first; then the steps are timed in rounds, one step of each variant per
round, so a change of the machine's load hits all variants alike. Reports the median
milliseconds per step (compilation excluded) and its ratio to the dense grids. The rays come
from the built-in scene of configs/fast.py (its batch of 2048 rays x 64 samples). Measured
figures: docs/hashgrid.md.
"""

from absl import app, flags

from nerf_jax import cli
from nerf_jax.backend import errors
from nerf_jax.bench.step_time import step_times
from nerf_jax.configs import fast
from nerf_jax.configs import hash as hash_config


def variants(log2_sizes, float16):
  """[(name, config)]: fast.py's grids, then configs/hash.py at each table size."""
  out = [("grid 32,64,128", fast.get_config())]
  for log2 in log2_sizes:
    for dtype in ("float32", "float16") if float16 else ("float32",):
      config = hash_config.get_config()
      config.model.hash.log2_size = log2
      config.model.hash.gather_dtype = dtype
      out.append((f"hash 2^{log2}" + (" f16" if dtype == "float16" else ""), config))
  return out


def main(argv=None):
  log2_sizes = flags.DEFINE_list("log2_sizes", ["14", "16", "17", "18", "19"],
                                 "hash table sizes, log2")
  steps = flags.DEFINE_integer("steps", 20, "timed steps per variant")
  num_views = flags.DEFINE_integer("num_views", 20, "views of the built-in scene")
  float16 = flags.DEFINE_bool("float16", False, "also time hash_dtype=float16")

  def run(_):
    sizes = [int(s) for s in log2_sizes.value]
    results = step_times(variants(sizes, float16.value), steps.value, num_views.value)
    grid_ms = next(iter(results.values()))[0]
    print(f"{'variant':<18} {'params':>10} {'ms/step':>9} {'x grid':>7}")
    for name, (ms, params) in results.items():
      print(f"{name:<18} {params:>10} {ms:>9.1f} {ms / grid_ms:>7.2f}")

  app.run(lambda argv: cli.run_main(lambda: run(argv)), argv=argv, flags_parser=errors.parse_flags)


if __name__ == "__main__":
  main()
