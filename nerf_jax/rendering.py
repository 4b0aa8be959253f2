"""The old import path of compositing.py (`nerf_jax.rendering.composite` stays importable)."""

from nerf_jax.compositing import (EMPTY_ACC, MAX_DENSITY, composite, compute_weights,  # noqa: F401
                                  disparity, exclusive_cumsum, one_minus_exp_neg)
