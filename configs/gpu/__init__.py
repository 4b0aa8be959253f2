"""Configs chosen for one GPU (instant-ngp-like sizes), unmeasured until a GPU session measures
them: docs/gpu.md#gpu-configurations-unmeasured."""
