"""Tests of the NDC transform for forward-facing scenes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import ndc
from nerf_jax.cameras import rays as rays_lib

W, H, FX, FY, NEAR = 40, 30, 35.0, 33.0, 1.5


def _reference(origins, directions, fx, fy, width, height, near):
  """The textbook formulas in float64, written out per component."""
  o = np.array(origins, np.float64)
  d = np.array(directions, np.float64)
  t = -(near + o[..., 2]) / d[..., 2]
  o = o + t[..., None] * d
  ax, ay = -2.0 * fx / width, -2.0 * fy / height
  o_ndc = np.stack([ax * o[..., 0] / o[..., 2], ay * o[..., 1] / o[..., 2],
                    1.0 + 2.0 * near / o[..., 2]], -1)
  d_ndc = np.stack([ax * (d[..., 0] / d[..., 2] - o[..., 0] / o[..., 2]),
                    ay * (d[..., 1] / d[..., 2] - o[..., 1] / o[..., 2]),
                    -2.0 * near / o[..., 2]], -1)
  return o_ndc, d_ndc


def _project(points, fx=FX, fy=FY, width=W, height=H, near=NEAR):
  """World points -> NDC points, float64 (the map of the module docstring)."""
  x, y, z = points[..., 0], points[..., 1], points[..., 2]
  return np.stack([-2.0 * fx / width * x / z, -2.0 * fy / height * y / z,
                   1.0 + 2.0 * near / z], -1)


def _forward_rays(num=200, seed=0):
  """Rays of cameras near the origin looking roughly down -z, float64 [num, 3] each."""
  rng = np.random.default_rng(seed)
  origins = rng.uniform(-0.3, 0.3, (num, 3))
  directions = np.concatenate([rng.uniform(-0.6, 0.6, (num, 2)), -np.ones((num, 1))], -1)
  return origins, directions * rng.uniform(0.5, 2.0, (num, 1))  # any length


def _ndc(origins, directions, **kw):
  out = ndc.ndc_rays(origins, directions, FX, W, H, NEAR, focal_y=FY, **kw)
  return tuple(np.asarray(a, np.float64) for a in out)


def test_matches_reference_formula():
  origins, directions = _forward_rays()
  o_ndc, d_ndc = _ndc(origins, directions)
  o_ref, d_ref = _reference(origins, directions, FX, FY, W, H, NEAR)
  assert o_ndc.shape == d_ndc.shape == (200, 3)
  np.testing.assert_allclose(o_ndc, o_ref, atol=1e-5)
  np.testing.assert_allclose(d_ndc, d_ref, atol=1e-5)
  single = ndc.ndc_rays(origins, directions, FX, W, H, NEAR)  # focal_y defaults to focal
  np.testing.assert_allclose(single[1], _reference(origins, directions, FX, FX, W, H, NEAR)[1],
                             atol=1e-5)
  assert single[0].dtype == single[1].dtype == jnp.float32


def test_near_plane_maps_to_minus_one_and_infinity_to_plus_one():
  origins, directions = _forward_rays()
  o_ndc, d_ndc = _ndc(origins, directions)
  np.testing.assert_array_equal(o_ndc[:, 2], -1.0)  # the origin moved onto z = -near
  np.testing.assert_array_equal(d_ndc[:, 2], 2.0)  # s = 1 is z_ndc = +1
  far_points = origins + 1e7 * directions
  np.testing.assert_allclose(_project(far_points)[:, 2], 1.0, atol=1e-6)
  np.testing.assert_allclose(_project(far_points), o_ndc + d_ndc, atol=1e-4)  # s -> 1


def test_world_points_on_a_ray_lie_on_its_ndc_ray():
  origins, directions = _forward_rays()
  o_ndc, d_ndc = _ndc(origins, directions)
  t_near = -(NEAR + origins[:, 2]) / directions[:, 2]
  previous = -np.inf
  for dt in (0.0, 0.5, 3.0, 40.0):
    points = origins + (t_near + dt)[:, None] * directions  # on or beyond the near plane
    s = 1.0 - NEAR / -points[:, 2]  # the NDC parameter: linear in disparity 1 / depth
    np.testing.assert_allclose(_project(points), o_ndc + s[:, None] * d_ndc, atol=2e-5)
    assert np.all((s > -1e-12) & (s < 1.0) & (s > previous))  # [0, 1), in order along the ray
    previous = s


def test_straight_lines_stay_straight():
  rng = np.random.default_rng(1)
  a = rng.uniform(-1, 1, (100, 3)) - [0, 0, 2.5]  # segments in front of the near plane, not
  b = a + rng.uniform(-1, 1, (100, 3)) - [0, 0, 1.5]  # parallel to it (see the next test)
  pa, pb = _project(a), _project(b)
  for u in (0.25, 0.5, 0.9):
    pm = _project(a + u * (b - a))
    cross = np.cross(pm - pa, pb - pa)
    np.testing.assert_allclose(cross, 0.0, atol=1e-9)
  # a line that is not a camera ray: its NDC ray (from `ndc_rays`) holds its projected points
  o_ndc, d_ndc = _ndc(a, b - a)
  np.testing.assert_allclose(np.cross(_project(a + 0.5 * (b - a)) - o_ndc, d_ndc), 0.0,
                             atol=1e-4)


def test_camera_frustum_maps_to_the_unit_square():
  origins, directions = rays_lib.get_rays(H, W, FX, np.eye(4))  # pixel corners, focal FX
  o_ndc, d_ndc = (np.asarray(a) for a in ndc.ndc_rays(origins, directions, FX, W, H, NEAR))
  corner = o_ndc[0, 0] + 0.7 * d_ndc[0, 0]
  np.testing.assert_allclose(corner[:2], [-1.0, 1.0], atol=1e-6)  # top-left image corner
  assert np.all(np.abs(o_ndc[..., :2] + d_ndc[..., :2]) <= 1.0 + 1e-6)
  np.testing.assert_allclose(d_ndc[..., :2], 0.0, atol=1e-6)  # rays from the origin stay put


@pytest.mark.parametrize("direction", [[1.0, 0.5, 0.0], [1.0, 0.0, -0.0], [0.0, 0.0, 0.0]])
def test_rays_parallel_to_the_image_plane_stay_finite(direction):
  origins = jnp.array([[0.1, -0.2, 0.3]])
  directions = jnp.array([direction])
  o_ndc, d_ndc = ndc.ndc_rays(origins, directions, FX, W, H, NEAR)
  assert np.all(np.isfinite(o_ndc)) and np.all(np.isfinite(d_ndc))
  loss = lambda o, d: sum(jnp.sum(a) for a in ndc.ndc_rays(o, d, FX, W, H, NEAR))
  grads = jax.grad(loss, argnums=(0, 1))(origins, directions)
  assert all(np.all(np.isfinite(g)) for g in grads)


def test_jit_and_batch_shapes():
  origins, directions = _forward_rays(24)
  fn = jax.jit(ndc.ndc_rays, static_argnums=(3, 4))
  o_ndc, d_ndc = fn(origins.reshape(2, 3, 4, 3), directions.reshape(2, 3, 4, 3), FX, W, H, NEAR)
  assert o_ndc.shape == d_ndc.shape == (2, 3, 4, 3)
  o_ref, d_ref = _reference(origins, directions, FX, FX, W, H, NEAR)
  np.testing.assert_allclose(np.asarray(o_ndc).reshape(-1, 3), o_ref, atol=1e-5)
  np.testing.assert_allclose(np.asarray(d_ndc).reshape(-1, 3), d_ref, atol=1e-5)
