"""Tests of nerf_jax.cameras.rays against closed forms and brute-force loops."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import rays

# One image size for every test and jitted entry points: few compilations keep the suite fast.
HEIGHT, WIDTH = 4, 6
get_rays = jax.jit(rays.get_rays, static_argnums=(0, 1))
get_rays_intrinsics = jax.jit(rays.get_rays_intrinsics, static_argnums=(0, 1))
safe_normalize = jax.jit(rays.safe_normalize)


def _c2w(rows):
  """A [rows, 4] camera-to-world matrix with a generic rotation and translation."""
  return rays.pose_spherical(37.0, -23.0, 3.5)[:rows]


@pytest.mark.parametrize("pixel_center", [0.0, 0.5])
@pytest.mark.parametrize("rows", [3, 4])
def test_project_lands_on_the_pixel_whose_ray_hits_the_point(pixel_center, rows):
  focal = 7.0
  c2w = _c2w(rows)
  origins, directions = map(np.asarray, get_rays(HEIGHT, WIDTH, focal, c2w, pixel_center))
  rng = np.random.default_rng(0)
  for _ in range(10):
    i, j = rng.integers(WIDTH), rng.integers(HEIGHT)
    o, d = origins[j, i].astype(np.float64), directions[j, i].astype(np.float64)
    point = o + rng.uniform(1.0, 5.0) * d
    ij = rays.project(point, HEIGHT, WIDTH, focal, c2w, pixel_center)
    np.testing.assert_allclose(ij, [i, j], atol=1e-4)
    # And the converse: the ray of the pixel `project` names passes within 1e-4 of the point.
    ci, cj = np.round(ij).astype(int)
    o, d = origins[cj, ci].astype(np.float64), directions[cj, ci].astype(np.float64)
    assert np.linalg.norm(np.cross(point - o, d)) / np.linalg.norm(d) < 1e-4


@pytest.mark.parametrize("pixel_center", [0.0, 0.5])
@pytest.mark.parametrize("rows", [3, 4])
def test_get_rays_matches_closed_formula(pixel_center, rows):
  focal = 4.5
  c2w = _c2w(rows)
  origins, directions = get_rays(HEIGHT, WIDTH, focal, c2w, pixel_center)
  assert origins.shape == directions.shape == (HEIGHT, WIDTH, 3)
  assert directions.dtype == jnp.float32
  origins, directions = np.asarray(origins), np.asarray(directions)
  rot = c2w[:3, :3].astype(np.float64)
  for j in range(HEIGHT):
    for i in range(WIDTH):
      cam = np.array([(i + pixel_center - WIDTH / 2) / focal,
                      -(j + pixel_center - HEIGHT / 2) / focal, -1.0])
      np.testing.assert_allclose(directions[j, i], rot @ cam, atol=1e-6)
      np.testing.assert_array_equal(origins[j, i], c2w[:3, 3])


def test_get_rays_intrinsics_general_camera():
  fx, fy, cx, cy = 5.0, 3.0, 1.25, 2.75  # fx != fy, principal point off centre
  c2w = _c2w(4)
  _, directions = get_rays_intrinsics(HEIGHT, WIDTH, (fx, fy, cx, cy), c2w, 0.5)
  directions = np.asarray(directions)
  rot = c2w[:3, :3].astype(np.float64)
  for j in range(HEIGHT):
    for i in range(WIDTH):
      cam = np.array([(i + 0.5 - cx) / fx, -(j + 0.5 - cy) / fy, -1.0])
      np.testing.assert_allclose(directions[j, i], rot @ cam, atol=1e-6)
  # Centred intrinsics agree with get_rays.
  _, d_ref = get_rays(HEIGHT, WIDTH, 5.0, c2w, 0.0)
  _, d_int = get_rays_intrinsics(HEIGHT, WIDTH, (5.0, 5.0, WIDTH / 2, HEIGHT / 2), c2w, 0.0)
  np.testing.assert_allclose(d_int, d_ref, atol=1e-7)


def test_camera_space_z_is_minus_one():
  """t is z-depth: every direction has camera-space z = -1."""
  c2w = _c2w(4)
  _, directions = get_rays(HEIGHT, WIDTH, 6.0, c2w, 0.0)
  cam = np.asarray(directions, np.float64) @ c2w[:3, :3].astype(np.float64)  # R^T d
  np.testing.assert_allclose(cam[..., 2], -1.0, atol=1e-6)


@pytest.mark.parametrize("theta", [0.0, 90.0, 211.0])
@pytest.mark.parametrize("phi", [-30.0, 0.0, -75.0])
def test_pose_spherical_conventions(theta, phi):
  radius = 4.0
  pose = rays.pose_spherical(theta, phi, radius).astype(np.float64)
  assert pose.shape == (4, 4)
  np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])
  rot, centre = pose[:3, :3], pose[:3, 3]
  np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-6)
  np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-6)
  np.testing.assert_allclose(np.linalg.norm(centre), radius, rtol=1e-6)
  # The camera's -z axis points at the origin.
  np.testing.assert_allclose(-rot[:, 2], -centre / radius, atol=1e-6)
  # Elevation: z = -radius·sin(phi), so phi = -30 puts the camera above the xy-plane.
  np.testing.assert_allclose(centre[2], -radius * math.sin(math.radians(phi)), atol=1e-5)


def test_pose_spherical_reference_values():
  """theta = 0, phi = -30: the Keras reference's first orbit pose, worked out by hand."""
  pose = rays.pose_spherical(0.0, -30.0, 4.0).astype(np.float64)
  s, c = 0.5, math.sqrt(3) / 2
  np.testing.assert_allclose(pose[:3, 3], [0.0, 4 * c, 4 * s], atol=1e-6)
  # Image right is world -x; image up leans toward -y: the camera looks down by 30 degrees.
  np.testing.assert_allclose(pose[:3, 0], [-1, 0, 0], atol=1e-6)
  np.testing.assert_allclose(pose[:3, 1], [0, -s, c], atol=1e-6)


def test_orbit_poses_circle_the_origin():
  poses = rays.orbit_poses(num_frames=8, phi=-30.0, radius=4.0)
  assert poses.shape == (8, 4, 4) and poses.dtype == np.float32
  np.testing.assert_allclose(poses[:, 2, 3], 2.0, atol=1e-5)  # constant height radius·sin(30°)
  angles = np.arctan2(poses[:, 1, 3], poses[:, 0, 3])
  steps = np.mod(np.diff(angles), 2 * np.pi)
  np.testing.assert_allclose(np.minimum(steps, 2 * np.pi - steps), 2 * np.pi / 8, atol=1e-5)


def test_spiral_poses_look_at_focus():
  focus_depth = 5.0
  poses = rays.spiral_poses(np.eye(4), np.array([0.3, 0.2, 0.1]), focus_depth, num_frames=6)
  focus = np.array([0.0, 0.0, -focus_depth])
  for pose in poses.astype(np.float64):
    rot = pose[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-6)
    to_focus = focus - pose[:3, 3]
    np.testing.assert_allclose(-rot[:, 2], to_focus / np.linalg.norm(to_focus), atol=1e-6)


def test_safe_normalize_value_and_gradient():
  v = np.array([[3.0, 0.0, 4.0], [0.0, -2.0, 0.0], [1e-8, 0.0, 0.0], [0.0, 0.0, 0.0]],
               np.float32)
  np.testing.assert_allclose(safe_normalize(v), [[0.6, 0.0, 0.8], [0.0, -1.0, 0.0],
                                                 [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], rtol=1e-6)
  # Finite Jacobian everywhere, the zero vector included.
  jac = jax.jit(jax.vmap(jax.jacobian(rays.safe_normalize)))(v)
  assert np.all(np.isfinite(jac))
  np.testing.assert_allclose(jac[0], (np.eye(3) - np.outer([0.6, 0, 0.8], [0.6, 0, 0.8])) / 5,
                             atol=1e-6)


def test_rays_pytree_reshape_and_viewdirs():
  origins, directions = get_rays(HEIGHT, WIDTH, 2.0, _c2w(4), 0.0)
  r = rays.Rays.create(origins, directions, 2.0, 6.0)
  flat = r.reshape(-1)
  assert flat.origins.shape == flat.directions.shape == (HEIGHT * WIDTH, 3)
  assert flat.near.shape == flat.far.shape == (HEIGHT * WIDTH,) and flat.shape == (HEIGHT * WIDTH,)
  viewdirs = jax.jit(lambda r: r.viewdirs)(flat)
  np.testing.assert_allclose(np.linalg.norm(viewdirs, axis=-1), 1.0, rtol=1e-6)
  np.testing.assert_allclose(viewdirs, flat.directions / np.linalg.norm(
      flat.directions, axis=-1, keepdims=True), rtol=1e-6)
  leaves = jax.tree_util.tree_leaves(r)
  assert len(leaves) == 5
