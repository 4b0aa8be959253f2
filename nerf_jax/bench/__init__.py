"""The accuracy-time benchmark: what accuracy costs in time, memory and rendering speed.

  python -m nerf_jax.bench --quick                      # sweeps of configs under equal budgets
  python -m nerf_jax.bench.render --workdir=runs/fast   # render speed and memory of a model
  python -m nerf_jax.bench.profile --config=fast        # where a train step's time goes
  python -m nerf_jax.bench.standard --blender=DIR --out=runs/standard   # the papers' benchmarks
  python -m nerf_jax.bench.regret --scene=diffuse --seconds=60   # auto against its alternatives

command_line.py  how a command line runs (absl flags, --config and --config.FIELD overrides)
cli.py           the sweep's command line (render.py and profile.py hold their own)
sweeps.py        the sweeps as data; a command's Request -> the configs it runs
runner.py        a sweep: each run in its own subprocess, records into results.jsonl
timed_run.py     one run: the library's train step under the bench's clock, probes, its record
measure.py       the instruments: pausable clock, timed compiles and calls, matmul peak, FLOPs, RSS
report.py        results.md and the plots (matplotlib: the `bench` extra)
render.py        frame, video and big-frame memory of a trained workdir
profile.py       each stage of a train step timed alone
standard.py      the standard benchmarks (NeRF-synthetic, LLFF, mip-NeRF 360, fox) by the papers'
                 protocols on the archives as unpacked, beside the published figures
regret_plan.py   the regret's runs: auto's config, each decision flipped alone, other configs
regret.py        auto's regret: those runs at equal time, results.jsonl, table.md, the picture
docs/benchmark.md explains every number; docs/benchmarks.md the standard benchmarks;
docs/regret.md auto's regret.
"""
