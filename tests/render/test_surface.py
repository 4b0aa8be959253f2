"""Mesh export recovers a known surface: a sphere, from a density function and from a field, and
the objects of the built-in `diffuse` scene."""

import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from nerf_jax.data import scenes
from nerf_jax.render import surface
from nerf_jax.run import experiment
from nerf_jax.run.signature import model_signature, state_template
from nerf_jax.train import checkpoints
from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from tests.helpers import small_config

from tests.helpers import ROOT


def _sphere_density(radius, centre=(0.0, 0.0, 0.0), scale=100.0):
  """sigma = scale·(radius - |x - centre|): the sphere is the level set sigma = 0."""
  return lambda p: scale * (radius - np.linalg.norm(p - np.asarray(centre), axis=-1))


@pytest.mark.parametrize("resolution", [24, 61])
def test_sphere_radius_within_a_voxel(resolution):
  radius, centre, bound, threshold = 0.63, (0.1, -0.2, 0.05), 1.0, 5.0
  density = surface.sample_grid(_sphere_density(radius, centre), bound, resolution, chunk=4096)
  vertices, faces, normals = surface.marching_cubes(density, threshold, bound)
  voxel = 2 * bound / (resolution - 1)
  distance = np.linalg.norm(vertices - centre, axis=-1)
  truth = radius - threshold / 100.0  # where sigma = threshold
  assert np.abs(distance - truth).max() < voxel
  # Outward normals, and faces wound counter-clockwise seen from outside.
  outward = (vertices - centre) / distance[:, None]
  assert np.all(np.sum(normals * outward, -1) > 0.9)
  a, b, c = (vertices[faces[:, k]] for k in range(3))
  assert np.all(np.sum(np.cross(b - a, c - a) * ((a + b + c) / 3 - centre), -1) > 0)


def _signed_distance(shape, points):
  """Exact signed distance float [P] to a Sphere, Box or Cylinder of the scene library."""
  p = points - np.asarray(shape.center)
  if isinstance(shape, Sphere):
    return np.linalg.norm(p, axis=-1) - shape.radius
  if isinstance(shape, Box):
    q = np.abs(p) - 0.5 * np.asarray(shape.size)
  else:
    assert isinstance(shape, Cylinder)
    q = np.stack([np.linalg.norm(p[:, :2], axis=-1) - shape.radius,
                  np.abs(p[:, 2]) - 0.5 * shape.height], -1)
  return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(-1), 0.0)


def test_built_in_scene_surfaces_within_a_voxel():
  shapes = [o.shape for o in scenes.get_scene("diffuse").objects]
  occupancy = lambda p: 100.0 * np.any([_signed_distance(s, p) <= 0 for s in shapes], axis=0)
  bound, resolution = 1.2, 49
  voxel = 2 * bound / (resolution - 1)
  density = surface.sample_grid(occupancy, bound, resolution, chunk=8192)
  vertices, faces, _ = surface.marching_cubes(density, 50.0, bound)
  assert len(faces) > 1000
  distances = np.abs(np.stack([_signed_distance(s, vertices) for s in shapes]))
  # Every vertex is within a voxel of some object's surface...
  assert distances.min(axis=0).max() < voxel
  # ...and where only the red sphere (radius 0.5 at the origin) is near, it recovers its radius.
  red = shapes[0]
  assert isinstance(red, Sphere) and red.radius == 0.5
  alone = np.delete(distances, 0, axis=0).min(axis=0) > 3 * voxel
  assert alone.sum() > 100
  radii = np.linalg.norm(vertices[alone] - np.asarray(red.center), axis=-1)
  assert np.abs(radii - red.radius).max() < voxel


def test_threshold_without_a_surface_is_refused():
  density = surface.sample_grid(_sphere_density(0.5), 1.0, 8)
  with pytest.raises(ValueError, match="--threshold=1000: no surface"):
    surface.marching_cubes(density, 1000.0, 1.0)


def test_ply_round_trip(tmp_path):
  rng = np.random.default_rng(0)
  vertices = rng.normal(size=(7, 3)).astype(np.float32)
  faces = rng.integers(0, 7, size=(5, 3)).astype(np.int32)
  colors = rng.integers(0, 256, size=(7, 3)).astype(np.uint8)
  path = str(tmp_path / "m.ply")
  surface.write_ply(path, vertices, faces, colors)
  with open(path, "rb") as f:
    assert f.read(3) == b"ply"
  back = surface.read_ply(path)
  for a, b in zip(back, (vertices, faces, colors)):
    np.testing.assert_array_equal(a, b)
  surface.write_ply(path, vertices, faces)
  assert surface.read_ply(path)[2] is None


RADIUS, RED = 0.6, np.array([250, 5, 5])


def _sphere_field_workdir(workdir):
  """A workdir whose checkpoint is a grid field with density 1000·relu(RADIUS - |x|) and colour
  sigmoid(4, -4, -4) everywhere (the grid holds the signed distance; the MLP passes it on)."""
  config = small_config({"model.encoding": "grid", "model.grid.resolutions": (33,),
                         "model.grid.features": 1, "model.grid_bound": 1.0, "model.width": 4,
                         "model.density_activation": "relu"})
  state = jax.tree_util.tree_map(lambda s: np.zeros(s.shape, s.dtype),
                                 state_template(experiment.setup(config)))
  params = state.params
  net = params["coarse"]
  axis = np.linspace(-1.0, 1.0, 33)
  x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
  net["grid_33"] = (RADIUS - np.sqrt(x ** 2 + y ** 2 + z ** 2))[..., None].astype(np.float32)
  net["hidden"]["kernel"][0, 0] = 1.0
  net["sigma"]["kernel"][0, 0] = 1000.0
  net["rgb"]["bias"][:] = [4.0, -4.0, -4.0]
  state = state.replace(params=params)
  os.makedirs(workdir)
  with open(os.path.join(workdir, "config.json"), "w") as f:
    f.write(config.to_json())
  checkpoints.save(workdir, 1, state, model_signature(config))
  return config


@pytest.mark.slow  # render.py in a process
def test_render_mesh_mode_recovers_the_sphere_of_a_field(tmp_path):
  workdir = str(tmp_path / "sphere")
  _sphere_field_workdir(workdir)
  res = subprocess.run([sys.executable, "render.py", f"--workdir={workdir}",
                        "--mode=mesh", "--resolution=41", "--threshold=1"], cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=ROOT), capture_output=True, text=True,
                       timeout=300)
  assert res.returncode == 0, res.stderr[-2000:]
  path = os.path.join(workdir, "mesh", "mesh.ply")
  assert f"to {path}" in res.stdout
  vertices, faces, colors = surface.read_ply(path)
  voxel = 2.0 / 40
  assert len(faces) > 100
  assert np.abs(np.linalg.norm(vertices, axis=-1) - RADIUS).max() < voxel
  assert np.all(np.abs(colors.astype(int) - RED) <= 1)
