"""Dense grids: interpolation and ray-box bounds against brute force; the box-restricted fast path
renders what the plain path renders."""


import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.fields.encodings import grid
from nerf_jax.render import renderer
from nerf_jax.cameras import rays as rays_lib
from nerf_jax.cameras.rays import Rays, get_rays, pose_spherical
from tests.helpers import TINY_GRID, jitted, ray_renderer, small_config, trilinear_brute


def test_trilinear_matches_brute_force_and_hits_lattice_values():
  rng = np.random.default_rng(0)
  g = rng.standard_normal((5, 5, 5, 3)).astype(np.float32)
  u = rng.random((50, 3)).astype(np.float32)
  u[0] = [0.0, 0.0, 0.0]
  u[1] = [1.0, 1.0, 1.0]
  u[2] = [0.25, 0.5, 0.75]  # a lattice point of a 5^3 grid
  got = np.asarray(grid.trilinear(jnp.asarray(g), jnp.asarray(u)))
  want = np.stack([trilinear_brute(g, p) for p in u])
  np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
  np.testing.assert_allclose(got[2], g[1, 2, 3], atol=1e-6)
  np.testing.assert_allclose(got[1], g[4, 4, 4], atol=1e-6)


def test_trilinear_gradient_is_the_interpolation_weights():
  g = jnp.zeros((4, 4, 4, 1))
  u = jnp.array([[0.1, 0.5, 0.9]])
  grad = jax.grad(lambda g: grid.trilinear(g, u).sum())(g)
  assert abs(float(grad.sum()) - 1.0) < 1e-6  # the weights are a partition of unity
  assert int(jnp.sum(grad > 0)) == 8


def _box_bounds_brute(o, d, bound, near, far, n=200001):
  t = np.linspace(near, far, n)
  p = o[None] + t[:, None] * d[None]
  inside = np.all(np.abs(p) <= bound, axis=-1)
  return (t[inside].min(), t[inside].max()) if inside.any() else None


def test_ray_box_bounds_match_brute_force():
  origins, directions = get_rays(7, 7, 5.0, pose_spherical(30.0, -40.0, 4.0))
  o, d = np.asarray(origins).reshape(-1, 3), np.asarray(directions).reshape(-1, 3)
  t0, t1 = rays_lib.ray_box_bounds(jnp.asarray(o), jnp.asarray(d), 1.0, 2.0, 6.0)
  hits = 0
  for i in range(len(o)):
    brute = _box_bounds_brute(o[i], d[i], 1.0, 2.0, 6.0)
    if brute is None:
      assert t1[i] - t0[i] < 1e-3
    else:
      hits += 1
      np.testing.assert_allclose([t0[i], t1[i]], brute, atol=1e-3)
  assert hits > 5


def test_ray_box_bounds_axis_parallel_and_zero_directions_are_finite():
  o = jnp.array([[0.0, 0.0, 4.0], [2.0, 0.0, 4.0], [0.0, 0.0, 0.0]])
  d = jnp.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
  t0, t1 = rays_lib.ray_box_bounds(o, d, 1.0, 2.0, 6.0)
  assert np.all(np.isfinite(t0)) and np.all(np.isfinite(t1))
  np.testing.assert_allclose([t0[0], t1[0]], [3.0, 5.0], atol=1e-6)
  assert t1[1] == t0[1]  # parallel to the box, outside it: empty segment


def test_box_restricted_sampling_renders_the_plain_image():
  """Sampling only inside the box changes cost, not the image: the field is empty outside."""
  fast_rr = ray_renderer(small_config(TINY_GRID, base="fast", num_samples=256))  # in the box
  plain_rr = ray_renderer(small_config(TINY_GRID, base="fast", num_samples=1024,
                                       **{"data.scene_bound": 0.0}))  # over [near, far]
  variables = jitted(fast_rr.init)(jax.random.PRNGKey(0))
  params = variables["params"]
  # A "trained toy model": a dense blob in the middle of the box.
  level = params["coarse"]["grid_16"]
  params["coarse"]["grid_16"] = level.at[5:11, 5:11, 5:11].set(3.0)
  origins, directions = get_rays(12, 12, 15.0, pose_spherical(10.0, -30.0, 4.0))
  rays = Rays.create(origins.reshape(-1, 3), directions.reshape(-1, 3), 2.0, 6.0)
  fast = renderer.final(jitted(fast_rr.render)(variables, rays))
  plain = renderer.final(jitted(plain_rr.render)(variables, rays))
  assert float(jnp.max(fast["acc"])) > 0.5  # the blob is visible
  np.testing.assert_allclose(fast["rgb"], plain["rgb"], atol=2e-2)
  np.testing.assert_allclose(fast["acc"], plain["acc"], atol=2e-2)
  empty = np.asarray(fast["acc"]) < 1e-10
  np.testing.assert_array_equal(np.asarray(fast["depth"])[empty], 6.0)  # empty rays: far
