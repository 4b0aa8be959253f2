"""The accuracy-time benchmark: what accuracy costs in time, memory and rendering speed.

  python -m nerf_jax.bench --quick                      # sweeps of configs under equal budgets
  python -m nerf_jax.bench.render --workdir=runs/fast   # render speed and memory of a model
  python -m nerf_jax.bench.profile --config=fast        # where a train step's time goes
  python -m nerf_jax.bench.standard --blender=DIR --out=runs/standard   # the papers' benchmarks
  python -m nerf_jax.bench.regret --scene=diffuse --seconds=60   # auto against its alternatives

Every module, by what it is for. The sweeps (python -m nerf_jax.bench):
__main__.py      python -m nerf_jax.bench: runs cli.py's command
cli.py           the sweep's command line (render.py and profile.py hold their own)
sweeps.py        the sweeps as data; a command's Request -> the configs it runs
runner.py        a sweep: each run in its own subprocess, records into results.jsonl
timed_run.py     one run: the library's train step under the bench's clock, probes, its record
measure.py       the instruments: pausable clock, timed compiles and calls, matmul peak, FLOPs, RSS
report.py        results.md and the plots (matplotlib: the `bench` extra)

Shared by the commands:
command_line.py  how a command line runs (absl flags, --config and --config.FIELD overrides) and
                 the config a command trains (its fields set, auto keeps them)
child.py         child processes: this checkout on their path, a run with its output in a log
records.py       every record's stamp (UTC date, git revision, the machine), JSON-lines files

Speed and cost of one part:
render.py        frame, video and big-frame memory of a trained workdir
profile.py       each stage of a train step timed alone
step_time.py     train-step time of a sweep's configs side by side, in one process
hash_step.py     train-step time of the dense grids beside hash grids of several table sizes
encodings.py     train-step cost of the grid encodings (dense levels, TensoRF) at several sizes
scatter_add.py   whether the hash table's gradient falls into XLA's scatter-add trap here
throughput.py    steps a second of each shipped config, against the last record of its machine

Accuracy:
standard.py      the standard benchmarks (NeRF-synthetic, LLFF, mip-NeRF 360, fox) by the papers'
                 protocols on the archives as unpacked, beside the published figures
regret_plan.py   the regret's runs: auto's config, each decision flipped alone, other configs
regret.py        auto's regret: those runs at equal time, results.jsonl, table.md, the picture
regret_table.py  auto's regret on many scenes side by side on the machine's cores, one table
capture.py       photos without poses -> nerf-process -> train -> video, against the true poses
sfm_twin.py      whether the SfM twin (landmark_sfm) fails as a one-focal reconstruction does

The machine and the code:
check.py         a machine end to end: the main job, a short run per standard scene, quick suite
gpu_frontier.py  one script for a GPU box: configs/gpu/ on lego, fox, fern, a profile, scatter-add
fingerprint.py   one hash per shipped config: a refactor that changes none changes no behaviour

docs/measuring.md explains every number; docs/standard_benchmark.md the standard benchmarks;
docs/regret.md auto's regret.
"""
