"""Computations that must give the same answers on every backend: matmul precision and its CPU
emulation of a GPU, deterministic ops."""
