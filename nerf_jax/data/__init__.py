"""Datasets: the tiny_nerf .npz and Blender loaders, exporters and the built-in scenes."""

from nerf_jax.data.dataset import DataError, Dataset
from nerf_jax.data.loaders import load_blender, load_dataset, load_npz, parse_background
