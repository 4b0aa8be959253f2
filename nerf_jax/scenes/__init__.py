"""Built-in procedural scenes with an exact ground-truth simulator."""

from nerf_jax.scenes.builtin import (SCENES, TINY_NERF_FOCAL, forward_poses, get_scene,
                                     make_dataset, random_poses)
from nerf_jax.scenes.photos import held_out_with_own_looks, photographed
from nerf_jax.scenes.geometry import Box, Cylinder, Sphere
from nerf_jax.scenes.raycast import Rod
from nerf_jax.scenes.scene import Effects, Light, Material, Medium, Object, Scene
from nerf_jax.scenes.simulator import render_view, trace_rays
from nerf_jax.scenes.textures import Texture
