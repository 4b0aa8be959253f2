"""The hash table's gradient on this device: is it caught by XLA's scatter-add trap?

jaxlib 0.10.2 to 0.11 had a GPU scatter-add that slows down several hundred times when many
updates hit the same row (jax#38806, openxla/xla#46225, as issue 40 reports them). The hash
grid's gradient is such a scatter-add: every sample adds its 8 corner rows at each of L levels,
and the coarse levels, indexed densely, have few rows (16^3 = 4096 at instant-ngp's coarsest),
so hundreds of updates hit each of their rows in every step. This times, at a config's table
size and sample budget (compile excluded, median of --repeats calls):

  spread          the updates' rows drawn uniformly over the whole table (the fast case)
  coarsest level  the rows drawn uniformly over the coarsest level's rows
  one row         every update on row 0 (the trap's worst case)
  encoding        the gradient of hashgrid.encode at uniform random positions (the real one)
  clustered       the same with every position in one finest cell (every level: 8 rows)

A trap shows as 'one row' or 'clustered' far slower than 'spread' (the issue: several hundred
times); the same ratio near 1 says this jaxlib has no such trap. On an affected jaxlib,
`import nerf_jax` restores the native atomic (backend/gpu_atomics.py; the title says which
atomics ran); `NERF_JAX_CAS_ATOMICS=1` measures jaxlib's loop instead.

  python -m nerf_jax.bench.scatter_add                       # configs/gpu/lego.py's table
  python -m nerf_jax.bench.scatter_add --config=gpu/capture --out=scatter.json
  python -m nerf_jax.bench.scatter_add --smoke               # tiny, for the CPU's tests
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
from absl import app, flags

from nerf_jax.backend import gpu_atomics
from nerf_jax.bench import measure, records
from nerf_jax.fields.encodings import hash as hashgrid

SMOKE = {"levels": 4, "log2_size": 10, "max_resolution": 64, "samples": 1024}  # a CPU's seconds


def table_layout(hash_settings, smoke=False):
  """(resolutions tuple, log2_size, features, rows of each level) of config.model.hash (a dict
  or ConfigDict of its fields), shrunk to SMOKE with `smoke`."""
  h = dict(hash_settings)
  if smoke:
    h.update(levels=SMOKE["levels"], log2_size=SMOKE["log2_size"],
             max_resolution=SMOKE["max_resolution"])
  resolutions = hashgrid.level_resolutions(h["levels"], h["base_resolution"], h["max_resolution"])
  rows = hashgrid.level_rows(resolutions, h["log2_size"])
  return resolutions, h["log2_size"], h["features"], rows


def index_cases(level_rows, samples, key):
  """{case: int32 [samples, L, 8] table rows} of the scatter-only cases (see the module's list):
  level_rows: rows of each of the L levels."""
  total, shape = sum(level_rows), (samples, len(level_rows), 8)
  k1, k2 = jax.random.split(key)
  return {"spread": jax.random.randint(k1, shape, 0, total, jnp.int32),
          "coarsest level": jax.random.randint(k2, shape, 0, level_rows[0], jnp.int32),
          "one row": jnp.zeros(shape, jnp.int32)}


def scatter_ms(total_rows, features, index, repeats):
  """Median ms of zeros float32 [total_rows, features] .at[index].add(values float32 [*index.shape,
  features]): the table gradient's scatter alone."""
  values = jnp.full((*index.shape, features), 1e-3, jnp.float32)
  add = jax.jit(lambda v, i: jnp.zeros((total_rows, features), jnp.float32).at[i].add(v))
  return _median_ms(add, values, index, repeats=repeats)


def encode_grad_ms(layout, unit, repeats):
  """Median ms of the table's gradient through hashgrid.encode at positions unit float32
  [samples, 3] (a mean-squared loss on the features): gather, interpolation and scatter."""
  resolutions, log2_size, features, rows = layout
  table = 1e-2 * jax.random.normal(jax.random.PRNGKey(1), (sum(rows), features))
  loss = lambda t, u: jnp.mean(hashgrid.encode(t, u, resolutions, log2_size) ** 2)
  return _median_ms(jax.jit(jax.grad(loss)), table, unit, repeats=repeats)


def _median_ms(fn, *args, repeats):
  """Median wall milliseconds of jitted fn(*args), compiled first (excluded), blocking."""
  compiled, _ = measure.compile_jitted(fn, *args)
  times = measure.sample_seconds(lambda: jax.block_until_ready(compiled(*args)), repeats)
  return 1e3 * float(np.median(times))


def measure_cases(hash_settings, samples, repeats=10, smoke=False):
  """[{'case', 'ms', 'x spread', 'updates'}] of every case at config.model.hash's table
  (`hash_settings`) with `samples` samples per step."""
  layout = table_layout(hash_settings, smoke)
  resolutions, _, features, rows = layout
  samples = SMOKE["samples"] if smoke else samples
  key = jax.random.PRNGKey(0)
  times = {case: scatter_ms(sum(rows), features, index, repeats)
           for case, index in index_cases(rows, samples, key).items()}
  uniform = jax.random.uniform(key, (samples, 3))
  times["encoding"] = encode_grad_ms(layout, uniform, repeats)
  finest_cell = 1.0 / (max(resolutions) - 1)  # every position inside one cell of every level
  times["clustered"] = encode_grad_ms(layout, 0.5 + 0.5 * finest_cell * uniform, repeats)
  updates = samples * len(resolutions) * 8
  return [{"case": case, "ms": ms, "x spread": ms / times["spread"], "updates": updates}
          for case, ms in times.items()]


def table_lines(rows, title):
  """The rows of `measure_cases` as a markdown table under `title`."""
  lines = [title, "", "| case | ms | x spread |", "|---|---:|---:|"]
  lines += [f"| {r['case']} | {r['ms']:.2f} | {r['x spread']:.1f} |" for r in rows]
  return lines


def main(argv=None):
  config_name = flags.DEFINE_string("config", "gpu/lego", "The config whose hash table (and "
                                    "train.sample_budget, or batch_rays x num_samples) to use.")
  repeats = flags.DEFINE_integer("repeats", 10, "Timed calls per case.")
  smoke = flags.DEFINE_bool("smoke", False, f"A tiny table and {SMOKE['samples']} samples.")
  out = flags.DEFINE_string("out", "", "Also write the rows as JSON here.")

  def run(_):
    from nerf_jax import cli  # pylint: disable=import-outside-toplevel
    from nerf_jax.run import config_lib  # pylint: disable=import-outside-toplevel

    def body():
      config = config_lib.load(config_name.value)
      samples = config.train.sample_budget or config.train.batch_rays * config.num_samples
      rows = measure_cases(config.model.hash, samples, repeats.value, smoke.value)
      device = jax.devices()[0]
      title = (f"scatter-add check, {config_name.value}'s table"
               f"{' (smoke: tiny)' if smoke.value else ''}, {rows[0]['updates']:,} updates, "
               f"on {getattr(device, 'device_kind', device.platform)}, jax {jax.__version__}, "
               f"{gpu_atomics.describe()}")
      print("\n".join(table_lines(rows, title)), flush=True)
      if out.value:
        with open(out.value, "w") as f:
          json.dump(records.stamp({"title": title, "rows": rows}), f, indent=1)
    cli.run_main(body)

  app.run(run, argv=argv)


if __name__ == "__main__":
  main()
