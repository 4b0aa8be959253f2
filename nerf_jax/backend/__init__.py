"""Computations that must give the same answers on every backend: matmul precision and its CPU
emulation of a GPU, deterministic ops, random draws compiled flat (draws.py); and the command
lines' one-line errors (errors.py), in the lowest layer so that a command of any layer shares
them."""
