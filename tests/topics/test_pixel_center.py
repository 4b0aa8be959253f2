"""Pixel centres by format: a user who sets nothing gets rays through pixel centres for built-in
scenes, Blender and LLFF folders, and what a .npz says (corners for tiny_nerf's); keras_seed and
tiny_nerf pin corners; built-in data and rays always agree."""

import numpy as np
import pytest

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data import scenes
from nerf_jax.run import experiment
from nerf_jax.data import export
from nerf_jax.data.llff import export_llff
from nerf_jax.data.scenes import simulator
from tests.helpers import small_config

SMALL = {"data.num_views": 5, "data.image_size": 8, "data.holdout_from": 4}  # 4 + 1 views of 8²


def _expected_directions(exp, pose, p):
  """Brute force: pixel (i, j) looks along R @ [(i + p - cx)/fx, -(j + p - cy)/fy, -1]."""
  fx, fy, cx, cy = exp.train_ds.intrinsics
  out = np.zeros((exp.train_ds.height, exp.train_ds.width, 3))
  for j in range(out.shape[0]):
    for i in range(out.shape[1]):
      out[j, i] = pose[:3, :3] @ [(i + p - cx) / fx, -(j + p - cy) / fy, -1.0]
  return out


def _builtin_data_matches_rays(exp):
  """The built-in images are the simulator's render of exactly the rays training uses."""
  pose = exp.train_ds.poses[0]
  rays = exp.rays(pose)
  truth = simulator.trace_rays(scenes.get_scene(exp.config.data.scene),
                                np.asarray(rays.origins).reshape(-1, 3),
                                np.asarray(rays.directions).reshape(-1, 3), exp.near, exp.far)
  np.testing.assert_allclose(truth["rgb"].reshape(exp.train_ds.images[0].shape),
                             exp.train_ds.images[0], atol=1e-5)


def test_builtin_scenes_default_to_pixel_centres_and_data_agrees():
  exp = experiment.setup(small_config(SMALL))
  assert exp.config.data.pixel_center == -1 and exp.pixel_center == 0.5
  pose = exp.train_ds.poses[1]
  np.testing.assert_allclose(exp.rays(pose).directions, _expected_directions(exp, pose, 0.5),
                             atol=1e-6)
  _builtin_data_matches_rays(exp)


@pytest.mark.parametrize("base", ["keras_seed", "tiny_nerf"])
def test_reference_configs_pin_pixel_corners(base):
  exp = experiment.setup(small_config(SMALL, base=base))
  assert exp.pixel_center == 0.0
  pose = exp.train_ds.poses[0]
  np.testing.assert_allclose(exp.rays(pose).directions, _expected_directions(exp, pose, 0.0),
                             atol=1e-6)
  _builtin_data_matches_rays(exp)


def test_file_formats_default_to_their_own_pixel_centres(tmp_path):
  fog = scenes.make_dataset("fog", num_views=5, height=8, width=8, focal=11.1)
  assert fog.pixel_center == 0.5
  export.export_blender(fog, str(tmp_path / "blender"), split_at=4)
  export_llff(fog, str(tmp_path / "llff"))
  export.export_npz(fog, str(tmp_path / "fog.npz"))  # records its pixel centre
  export.export_npz(fog, str(tmp_path / "ref.npz"), rgb_only=True)  # the reference's arrays only
  on = lambda name, **fields: experiment.setup(small_config(
      SMALL, **{"data.path": str(tmp_path / name), "data.ndc": False}, **fields))
  got = {name: on(name).pixel_center for name in ("blender", "llff", "fog.npz", "ref.npz")}
  assert got == {"blender": 0.5, "llff": 0.5, "fog.npz": 0.5, "ref.npz": 0.0}
  assert on("blender", **{"data.pixel_center": 0.0}).pixel_center == 0.0


def test_a_bad_pixel_center_names_the_field():
  with pytest.raises(ValueError, match="config.data.pixel_center"):
    experiment.setup(small_config(SMALL, **{"data.pixel_center": -0.5}))


def test_project_inverts_the_default_rays():
  exp = experiment.setup(small_config(SMALL))
  pose = exp.train_ds.poses[0]
  rays = exp.rays(pose)
  point = np.asarray(rays.origins[3, 5] + 3.0 * rays.directions[3, 5])
  ij = rays_lib.project(point, 8, 8, exp.train_ds.focal, pose, exp.pixel_center)
  np.testing.assert_allclose(ij, [5, 3], atol=1e-4)
