"""Built-in procedural scenes with an exact ground-truth simulator."""

from nerf_jax.data.scenes.builtin import (SCENES, TINY_NERF_FOCAL, forward_poses, get_scene,
                                          make_dataset, random_poses)
from nerf_jax.data.scenes.photos import held_out_with_own_looks, photographed, without
from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.data.scenes.raycast import Rod
from nerf_jax.data.scenes.scene import Effects, Light, Material, Medium, Object, Scene
from nerf_jax.data.scenes.simulator import render_view, trace_rays
from nerf_jax.data.scenes.textures import Texture
