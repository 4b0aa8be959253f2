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


# Rays.radii (pixel_rays' with_radii): the pixel's cone, mip-NeRF's dx·2/√12.

def _ndc_direction_reference(i, j, fx, fy, cx, cy, c2w, width, height, near=1.0):
  """float64 [..., 3]: the NDC direction of pixel (i, j)'s ray (pixel centres), as the difference
  of the NDC images of its point at infinity and of its point on the plane z = -near: the NDC
  ray runs from the one (s = 0) to the other (s = 1)."""
  c2w = np.asarray(c2w, np.float64)
  cam = np.stack([(i + 0.5 - cx) / fx, -(j + 0.5 - cy) / fy, -np.ones_like(i)], axis=-1)
  d = cam @ c2w[:3, :3].T
  o = np.broadcast_to(c2w[:3, 3], d.shape)
  p = o + (-(near + o[..., 2]) / d[..., 2])[..., None] * d  # on the near plane
  sx, sy = -2.0 * fx / width, -2.0 * fy / height
  at_near = np.stack([sx * p[..., 0] / p[..., 2], sy * p[..., 1] / p[..., 2],
                      1.0 + 2.0 * near / p[..., 2]], axis=-1)
  at_infinity = np.stack([sx * d[..., 0] / d[..., 2], sy * d[..., 1] / d[..., 2],
                          np.ones_like(i)], axis=-1)
  return at_infinity - at_near


def test_base_radius_from_neighbouring_pixel_directions():
  """Brute force: distances between neighbouring pixels' directions of `rays.pixel_directions`
  (x: along a row, y: along a column), their geometric mean times 2/sqrt(12)."""
  for fx, fy in ((100.0, 100.0), (555.5, 420.0), (30.0, 60.0)):
    dirs = np.asarray(rays.pixel_directions(7, 9, fx, fy, 4.5, 3.5, 0.5), np.float64)
    dx = np.linalg.norm(dirs[:, 1:] - dirs[:, :-1], axis=-1)
    dy = np.linalg.norm(dirs[1:] - dirs[:-1], axis=-1)
    expected = np.sqrt(dx.mean() * dy.mean()) * 2 / np.sqrt(12)
    np.testing.assert_allclose(rays.base_radius(fx, fy), expected, rtol=1e-5)
    if fx == fy:  # mip-NeRF's dx·2/sqrt(12)
      np.testing.assert_allclose(rays.base_radius(fx, fy), dx.mean() * 2 / np.sqrt(12),
                                 rtol=1e-5)
  per_image = rays.base_radius(np.float32([100.0, 50.0]), np.float32([100.0, 50.0]))
  np.testing.assert_allclose(per_image, [0.01 / np.sqrt(3), 0.02 / np.sqrt(3)],
                             rtol=1e-6)


def test_rays_have_no_radii_unless_asked():
  kwargs = dict(height=4, width=5, intrinsics=(6.0, 7.0, 2.5, 2.0), c2w=np.eye(4), near=0.0,
                far=1.0)
  assert rays.camera_rays(**kwargs).radii is None
  thin, cones = rays.camera_rays(**kwargs), rays.camera_rays(**kwargs, with_radii=True)
  for a, b in zip((thin.origins, thin.directions, thin.viewdirs, thin.near, thin.far),
                  (cones.origins, cones.directions, cones.viewdirs, cones.near, cones.far)):
    np.testing.assert_array_equal(a, b)  # radii only add a field
  # A pinhole's pixels are 1/fx apart (and 1/fy) in the plane z = -1: radius 2/√12·√(dx·dy).
  expected = 2.0 / math.sqrt(12.0) / math.sqrt(6.0 * 7.0)
  assert cones.radii.shape == (4, 5)
  np.testing.assert_allclose(cones.radii, expected, rtol=1e-6)


def test_ndc_radius_is_the_distance_to_the_next_rows_ndc_direction():
  # Turned about z (forward-facing: the camera looks down -z), and moved.
  c2w = np.array([[0.96, -0.28, 0.0, 0.3], [0.28, 0.96, 0.0, -0.2], [0.0, 0.0, 1.0, 0.5]],
                 np.float32)
  height, width, intr = 6, 8, (9.0, 8.0, 4.2, 2.9)
  got = rays.camera_rays(height, width, intr, c2w, 0.0, 1.0, 0.5, use_ndc=True, with_radii=True)
  i, j = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64),
                     indexing="xy")
  ref = lambda jj: _ndc_direction_reference(i, jj, *intr, c2w, width, height)
  np.testing.assert_allclose(got.directions, ref(j), rtol=1e-5, atol=1e-6)
  distance = np.linalg.norm(ref(j + 1.0) - ref(j), axis=-1)  # a finite difference of one row
  np.testing.assert_allclose(got.radii, 2.0 / math.sqrt(12.0) * distance, rtol=1e-4)
  # mip-NeRF's definition, with its quirk: rays of a camera at the world origin are parallel
  # in NDC (their directions all (0, 0, 2)), so that camera's radii are 0; this one is moved.
  assert np.all(got.radii > 1e-3)
