"""Configs chosen for one GPU (instant-ngp-like sizes); their measurements on one H200 are in
docs/gpu.md#measured-on-one-h200-2026-11-28."""
