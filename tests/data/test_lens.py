"""nerf_jax.data.lens: OpenCV distortion against pycolmap's own camera model and closed forms."""

import numpy as np
import pytest

from nerf_jax.data import lens

# The capture extra (structure from motion); the tests say how to install it when it is missing.
pycolmap = pytest.importorskip(
    "pycolmap", reason='needs pycolmap; install with: pip install -e ".[capture]"')

DIST = (-0.12, 0.03, 0.002, -0.0015)
INTRINSICS = (210.0, 205.0, 61.5, 58.25)


def _pycolmap_camera(model, params, size=(120, 128)):
  return pycolmap.Camera(model=model, width=size[1], height=size[0], params=np.asarray(params))


def test_distort_closed_form_values():
  # x = 0.3, y = -0.2: r2 = 0.13, radial = 1 - 0.12 * 0.13 + 0.03 * 0.0169 = 0.984907,
  # x' = 0.3 * radial + 2 * 0.002 * 0.3 * -0.2 + -0.0015 * (0.13 + 0.18)
  # y' = -0.2 * radial + 0.002 * (0.13 + 0.08) + 2 * -0.0015 * 0.3 * -0.2
  expected = (0.2954721 - 0.00024 - 0.000465, -0.1969814 + 0.00042 + 0.00018)
  np.testing.assert_allclose(lens.distort(np.array([0.3, -0.2]), DIST), expected, atol=1e-7)


@pytest.mark.parametrize("model,params", [
    ("SIMPLE_PINHOLE", (200.0, 64.0, 60.0)),
    ("PINHOLE", (200.0, 190.0, 64.5, 60.0)),
    ("SIMPLE_RADIAL", (200.0, 64.0, 60.0, -0.08)),
    ("RADIAL", (200.0, 64.0, 60.0, -0.08, 0.02)),
    ("OPENCV", INTRINSICS + DIST),
])
def test_projection_matches_pycolmap(model, params):
  camera = _pycolmap_camera(model, params)
  intrinsics, dist = lens.from_colmap(model, params)
  rng = np.random.default_rng(0)
  points = np.concatenate([rng.uniform(-0.35, 0.35, (200, 2)), np.ones((200, 1))], -1)
  points *= rng.uniform(0.5, 3.0, (200, 1))
  np.testing.assert_allclose(lens.project(points, intrinsics, dist),
                             camera.img_from_cam(points), atol=1e-9)
  uv = rng.uniform(0, 120, (200, 2))  # and back: pixels -> normalised coordinates
  fx, fy, cx, cy = intrinsics
  xy = lens.undistort((uv - [cx, cy]) / [fx, fy], dist)
  np.testing.assert_allclose(xy, camera.cam_from_img(uv), atol=1e-9)


def test_undistort_inverts_distort():
  rng = np.random.default_rng(1)
  xy = rng.uniform(-0.5, 0.5, (500, 2))
  np.testing.assert_allclose(lens.undistort(lens.distort(xy, DIST), DIST), xy, atol=1e-12)
  k3 = DIST + (0.01,)
  np.testing.assert_allclose(lens.undistort(lens.distort(xy, k3), k3), xy, atol=1e-12)


def test_resample_is_identity_for_the_same_pinhole():
  image = np.random.default_rng(3).uniform(0, 1, (6, 9, 3))
  out = lens.resample(image, (8.0, 8.0, 4.5, 3.0), (0.0, 0.0, 0.0, 0.0), (8.0, 8.0, 4.5, 3.0),
                      (6, 9))
  np.testing.assert_allclose(out, image, atol=1e-12)


def test_unknown_colmap_model_is_one_line():
  with pytest.raises(ValueError, match="not supported"):
    lens.from_colmap("FOV", (1.0, 2.0, 3.0, 4.0, 5.0))
