"""Datasets: the tiny_nerf .npz, Blender, LLFF, transforms.json and COLMAP loaders, exporters and
the built-in scenes."""

from nerf_jax.data.dataset import DataError, Dataset
from nerf_jax.data.llff import export_llff, load_llff
from nerf_jax.data.loaders import (DataSettings, load_blender, load_dataset, load_npz,
                                   parse_background)
