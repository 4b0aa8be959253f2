"""Experiment.camera and Experiment.rays through an image's own camera (per-image cameras)."""

import numpy as np

from nerf_jax.data import export, convert_multiscale, scenes
from nerf_jax.run import experiment
from tests.helpers import small_config


def test_an_images_camera_and_rays(tmp_path):
  fog = scenes.make_dataset("fog", num_views=5, height=16, width=16, focal=22.2)
  export.export_blender(fog, str(tmp_path / "blender"), split_at=3)
  convert_multiscale.convert(str(tmp_path / "blender"), str(tmp_path / "ms"), levels=2)
  exp = experiment.setup(small_config({"data.path": str(tmp_path / "ms")}))
  focal = 22.2
  assert exp.camera()[:2] == (16, 16)  # the shared camera: training image 0's
  np.testing.assert_allclose(exp.camera()[2], (focal, focal, 8.0, 8.0), rtol=1e-6)
  height, width, intrinsics = exp.camera(image=3, dataset=exp.test_ds)
  assert (height, width) == (8, 8) and intrinsics == exp.test_ds.cameras.camera(3)[2]
  np.testing.assert_allclose(intrinsics, (focal / 2, focal / 2, 4.0, 4.0), rtol=1e-6)
  assert exp.camera(2.0, image=1)[:2] == (16, 16)  # training image 1 (8 px) at twice the size
  rays = exp.rays(exp.test_ds.poses[3], (height, width, intrinsics))
  assert rays.shape == (8, 8)
  # Through pixel centres: the centre ray of an even-sized image lies between the middle four.
  middle = np.asarray(rays.viewdirs[3:5, 3:5]).mean((0, 1))
  np.testing.assert_allclose(middle / np.linalg.norm(middle), -exp.test_ds.poses[3][:3, 2],
                             atol=1e-6)
