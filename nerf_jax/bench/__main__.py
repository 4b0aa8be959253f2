"""python -m nerf_jax.bench: train sweeps of NeRF configurations under equal budgets and measure
quality, speed and memory (docs/measuring.md explains every number; the flags: bench/cli.py).

  python -m nerf_jax.bench --quick --out=bench_out/quick
  python -m nerf_jax.bench --sweep=samples,width --config=mlp64 --budget_seconds=60
  python -m nerf_jax.bench --sweep=effects --steps=500 --config.model.width=128
  python -m nerf_jax.bench --sweep=configs --dry_run
"""

from nerf_jax.bench import cli

if __name__ == "__main__":
  cli.sweep_main()
