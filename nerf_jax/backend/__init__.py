"""Computations that must give the same answers on every backend: matmul precision and its CPU
emulation of a GPU, deterministic ops, random draws compiled flat (draws.py), native float
atomics for the GPU scatter-adds of jaxlib 0.10.2-0.11.0 (gpu_atomics.py); and the command
lines' one-line errors (errors.py), in the lowest layer so that a command of any layer shares
them."""
