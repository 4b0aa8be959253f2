"""Tests of nerf_jax.cameras.cones against references written here (float64 numpy).

The reference frustum: points o + t·d + offset, t with density proportional to t^2 on [t0, t1]
(inverse CDF of t^3), the offset uniform in the disc of radius radius·t perpendicular to d (our
conventions: d un-normalised, t z-depth). Monte Carlo tolerances are 5 standard errors of the
estimate (computed from the samples), so a correct implementation fails about once in 10^6.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import cones

pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: NaNs raise in this module


def frustum_samples(rng, origin, direction, radius, t0, t1, num):
  """float64 [num, 3]: points uniform (by volume) in the conical frustum between t0 and t1."""
  u, v, phi = rng.uniform(size=(3, num))
  t = np.cbrt(t0 ** 3 + u * (t1 ** 3 - t0 ** 3))  # density ∝ t^2
  rho = radius * t * np.sqrt(v)  # uniform in the disc of radius r(t) = radius·t
  d = np.asarray(direction, np.float64)
  # An orthonormal basis across the ray by Gram-Schmidt from a fixed vector (not cones.py's).
  e1 = np.array([0.3, 0.9, 0.1]) - d * (np.array([0.3, 0.9, 0.1]) @ d) / (d @ d)
  e1 /= np.linalg.norm(e1)
  e2 = np.cross(d / np.linalg.norm(d), e1)
  offset = rho[:, None] * (np.cos(2 * np.pi * phi)[:, None] * e1
                           + np.sin(2 * np.pi * phi)[:, None] * e2)
  return np.asarray(origin, np.float64) + t[:, None] * d + offset


def mc_moments(x):
  """Mean [3], covariance [3, 3] and 5 standard errors of each [3], [3, 3] of samples [N, 3]."""
  n = len(x)
  mean = x.mean(0)
  c = x - mean
  cov = c.T @ c / n
  prods = c[:, :, None] * c[:, None, :]
  return mean, cov, 5 * np.sqrt(np.diag(cov) / n), 5 * prods.std(0) / np.sqrt(n)


# (origin, direction (z-depth: camera z = -1, rotated), base radius, t0, t1)
FRUSTUMS = [
    ((0.1, -0.2, 0.3), (0.3, -0.2, -1.0), 0.05, 2.0, 2.6),
    ((0.0, 0.0, 0.0), (-1.2, 0.4, -0.9), 0.2, 0.0, 1.0),  # t0 = 0: the cone's tip
    ((1.0, 2.0, -1.0), (0.05, 1.1, -0.6), 0.01, 5.0, 5.01),  # short and thin
    ((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), 0.3, 1.0, 3.0),  # along an axis
]


@pytest.mark.parametrize("frustum", FRUSTUMS)
def test_frustum_gaussian_matches_monte_carlo(frustum):
  origin, direction, radius, t0, t1 = frustum
  x = frustum_samples(np.random.default_rng(0), origin, direction, radius, t0, t1, 400_000)
  mean, cov, mean_tol, cov_tol = mc_moments(x)
  args = (np.float32(origin), np.float32(direction), np.float32(radius),
          np.float32([t0]), np.float32([t1]))
  g_mean, g_cov = cones.frustum_gaussians(*args)
  _, g_var = cones.frustum_gaussians(*args, diagonal=True)
  assert g_mean.shape == (1, 3) and g_cov.shape == (1, 3, 3) and g_var.shape == (1, 3)
  scale = np.sqrt(np.max(np.diag(cov)))  # float32 rounding of positions of this spread
  np.testing.assert_array_less(np.abs(g_mean[0] - mean), mean_tol + 1e-6 * (1 + scale))
  np.testing.assert_array_less(np.abs(g_cov[0] - cov), cov_tol + 1e-6 * scale ** 2)
  np.testing.assert_allclose(g_var[0], np.diag(g_cov[0]), rtol=1e-6, atol=1e-12)
  # frustum_spreads: the same mean bit for bit, and the same covariance lifted from its
  # variances along and across the ray (what the contracted field takes).
  s_mean, t_var, r_var = cones.frustum_spreads(*args)
  np.testing.assert_array_equal(s_mean, g_mean)
  d = np.asarray(direction, np.float64)
  outer = np.outer(d, d)
  lifted = t_var[0] * outer + r_var[0] * (np.eye(3) - outer / (d @ d))
  np.testing.assert_allclose(lifted, g_cov[0], rtol=1e-5, atol=1e-6 * scale ** 2)


def test_frustum_moments_match_the_expanded_formulas_and_stay_stable():
  """Against E[t^k] = 3/(k+3)·(t1^(k+3) - t0^(k+3))/(t1^3 - t0^3) in float64; the stable form
  in float32 keeps short, far intervals (where the expanded one cancels) to 1e-5 relative."""
  t0 = np.array([0.0, 0.5, 2.0, 10.0, 1000.0, 1e6], np.float64)
  t1 = t0 + np.array([1.0, 0.5, 0.1, 1e-2, 1e-3, 1.0])
  # The reference sees the float32 inputs: 1000.001 rounds to float32 with 3% of hw's length.
  t0, t1 = np.float32(t0).astype(np.float64), np.float32(t1).astype(np.float64)
  moment = lambda k: 3.0 / (k + 3) * (t1 ** (k + 3) - t0 ** (k + 3)) / (t1 ** 3 - t0 ** 3)
  mu = 0.5 * (t0 + t1)
  e1 = moment(1)
  # Var[t] = E[(t - mu)^2] - (E[t] - mu)^2, both exact around the midpoint (no cancellation).
  t_var = np.array([_central_second_moment(a, b) for a, b in zip(t0, t1)]) - (e1 - mu) ** 2
  t_mean, var, r_var = cones.frustum_moments(np.float32(t0), np.float32(t1))
  np.testing.assert_allclose(t_mean, e1, rtol=1e-6)
  np.testing.assert_allclose(var, t_var, rtol=1e-4)
  np.testing.assert_allclose(r_var, moment(2) / 4.0, rtol=1e-6)


def _central_second_moment(t0, t1):
  """E[(t - mu)^2] for density ∝ t^2 on [t0, t1], mu the midpoint: exact polynomial integrals
  in the shifted variable s = t - mu (no cancellation), float64."""
  mu, hw = 0.5 * (t0 + t1), 0.5 * (t1 - t0)
  # ∫_{-hw}^{hw} s^2 (s + mu)^2 ds = 2 hw^5/5 + 2 mu^2 hw^3/3;
  # ∫_{-hw}^{hw} (s + mu)^2 ds = 2 hw^3/3 + 2 mu^2 hw.
  return (2 * hw ** 5 / 5 + 2 * mu ** 2 * hw ** 3 / 3) / (2 * hw ** 3 / 3 + 2 * mu ** 2 * hw)


def test_degenerate_intervals_are_finite_with_finite_gradients():
  t0 = jnp.array([0.0, 1.0, 1e8, 0.0], jnp.float32)
  t1 = jnp.array([0.0, 1.0, 1e8, 1e-30], jnp.float32)
  d = jnp.array([0.2, 0.1, -1.0], jnp.float32)

  def total(t0, t1, radius):
    mean, cov = cones.frustum_gaussians(jnp.zeros(3), d, radius, t0, t1)
    points, scales = cones.multisamples(jnp.zeros(3), d, radius, t0, t1)
    return jnp.sum(mean) + jnp.sum(cov) + jnp.sum(points) + jnp.sum(scales)

  value, grads = jax.value_and_grad(total, argnums=(0, 1, 2))(t0, t1, jnp.float32(0.01))
  assert np.isfinite(value) and all(np.all(np.isfinite(g)) for g in grads)
  t_mean, t_var, r_var = cones.frustum_moments(t0, t1)
  np.testing.assert_array_equal(t_var[:3], 0.0)  # a disc has no extent along the ray
  np.testing.assert_allclose(t_mean[:3], t0[:3])
  np.testing.assert_allclose(r_var[:3], t0[:3] ** 2 / 4, rtol=1e-6)


def test_perpendicular_basis_is_orthonormal():
  d = jnp.concatenate([jax.random.normal(jax.random.PRNGKey(0), (500, 3)),
                       jnp.eye(3), -jnp.eye(3), jnp.float32([[1e-20, 0, 3e4]])])
  a, b = cones.perpendicular_basis(d)
  u = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
  for v, w in ((a, b), (a, u), (b, u)):
    np.testing.assert_allclose(jnp.sum(v * w, axis=-1), 0.0, atol=1e-6)
  np.testing.assert_allclose(jnp.linalg.norm(a, axis=-1), 1.0, rtol=1e-6)
  np.testing.assert_allclose(jnp.linalg.norm(b, axis=-1), 1.0, rtol=1e-6)


def whitened_error(points, mean, cov):
  """Largest |eigenvalue| of Σ^-1/2 (Σ_points - Σ) Σ^-1/2: the covariance error of the six
  points relative to the Gaussian's own spread in every direction (float64)."""
  p = np.asarray(points, np.float64)
  c = p - p.mean(0)
  pc = c.T @ c / len(p)
  w, v = np.linalg.eigh(np.asarray(cov, np.float64))
  inv_sqrt = v @ np.diag(w ** -0.5) @ v.T
  return np.max(np.abs(np.linalg.eigvalsh(inv_sqrt @ (pc - cov) @ inv_sqrt)))


@pytest.mark.parametrize("key", [None, jax.random.PRNGKey(3)])
def test_multisamples_match_the_frustum_gaussian(key):
  """The six points' mean is the Gaussian's to float32 rounding. Their covariance differs by
  the slight anisotropy and t-correlation of offsets that grow with t (cones.multisamples): in
  whitened terms (whitened_error) 0.62·hw/mu, measured in float64 for hw/mu from 5e-4 to 0.25
  (closed form to first order: the offsets' anisotropy b·|sum_j j·exp(2i·theta_j)|/(3·mu) =
  0.39·hw/mu and their correlation with t 0.48·hw/mu, b = 0.338·hw the step of t_j). Bound:
  0.65·hw/mu, plus float32 rounding, which a flat frustum (wide and short) magnifies by its
  condition number: the covariance in world axes carries ~eps·λmax in its thinnest direction.
  Typical sampling (64 intervals over [2, 6]: hw/mu <= 0.016) stays within 1%."""
  rng = np.random.default_rng(1)
  o = np.float32([0.5, -1.0, 2.0])
  d = np.float32([0.3, 0.4, -1.0])
  mu = np.float32([2.0, 2.0, 2.0, 2.0, 3.0, 0.5])
  hw = np.float32([0.001, 0.01, 0.1, 0.5, 3.0, 0.5])  # hw/mu up to 1 (t0 = 0)
  radii = np.float32(rng.uniform(0.005, 0.5, size=(8,)))
  t0, t1 = (mu - hw)[None] * np.ones((8, 1), np.float32), (mu + hw)[None] * np.ones((8, 1),
                                                                                   np.float32)
  mean, cov = cones.frustum_gaussians(o, d, radii, t0, t1)
  points, scales = cones.multisamples(o, d, radii, t0, t1, key)
  assert points.shape == (8, 6, 6, 3) and scales.shape == (8, 6, 6)
  np.testing.assert_allclose(jnp.mean(points, axis=-2), mean, rtol=0, atol=2e-6 * 4)
  for i in range(8):
    for s in range(6):
      err = whitened_error(points[i, s], mean[i, s], cov[i, s])
      condition = np.linalg.cond(np.asarray(cov[i, s], np.float64))
      assert err <= 0.65 * hw[s] / mu[s] + 4 * 2.0 ** -23 * condition, (i, s, err)
  # The scales: the rings' radii, radius·t_j/sqrt(2), each point's distance from the ray.
  along = jnp.sum((points - o) * d, axis=-1) / jnp.sum(d * d)
  across = jnp.linalg.norm(points - o - along[..., None] * d, axis=-1)
  np.testing.assert_allclose(scales, across, rtol=1e-4, atol=1e-6)
  np.testing.assert_allclose(scales, radii[:, None, None] * along / np.sqrt(2), rtol=1e-4,
                             atol=1e-6)


def test_multisamples_are_deterministic_without_a_key_and_random_with_one():
  args = (jnp.zeros(3), jnp.float32([0, 0, -1]), jnp.float32(0.1), jnp.float32([[1.0, 2.0]]),
          jnp.float32([[1.5, 2.5]]))
  p1, _ = cones.multisamples(*args[:3], args[3][0], args[4][0])
  p2, _ = cones.multisamples(*args[:3], args[3][0], args[4][0])
  np.testing.assert_array_equal(p1, p2)
  # Along -z the offsets lie in the xy plane: the first hexagon has the angles HEXAGON (up to
  # one turn, and the orientation, of the basis), every other one is mirrored and turned by 30°.
  angles = np.arctan2(p1[..., 1], p1[..., 0])
  wrap = lambda a: np.abs(np.angle(np.exp(1j * a)))
  orientation = 1.0 if np.all(wrap(angles[0] - angles[0, 0] - cones.HEXAGON) < 1e-5) else -1.0
  relative = orientation * (angles - angles[0, 0])
  np.testing.assert_allclose(wrap(relative[0] - cones.HEXAGON), 0.0, atol=1e-5)
  np.testing.assert_allclose(wrap(relative[1] - cones.HEXAGON[::-1] - np.pi / 6), 0.0,
                             atol=1e-5)
  q1, _ = cones.multisamples(*args[:3], args[3][0], args[4][0], jax.random.PRNGKey(0))
  q2, _ = cones.multisamples(*args[:3], args[3][0], args[4][0], jax.random.PRNGKey(1))
  assert not np.allclose(q1, q2)


def test_the_jitters_mirror_and_turn_are_drawn_apart():
  """With a key, each hexagon's mirroring and its turn are independent draws: the share
  mirrored is 1/2 among the hexagons turned by less than pi and among the others (5 standard
  errors of a share of n: 5·sqrt(1/4n)); one draw for both would mirror exactly those turned
  by less than pi. Each frustum's mirroring and turn are read back from its points' angles
  about the ray (cones.perpendicular_basis, tested above)."""
  num = 4096
  t0 = jnp.linspace(1.0, 5.0, num, dtype=jnp.float32)
  origin, direction = jnp.float32([0.1, -0.2, 0.3]), jnp.float32([0.3, -0.4, -1.0])
  points, _ = cones.multisamples(origin, direction, jnp.float32(0.05), t0, t0 + 0.01,
                                 jax.random.PRNGKey(4))
  d = np.asarray(direction, np.float64) / np.linalg.norm(direction)
  rel = np.asarray(points, np.float64) - np.asarray(origin, np.float64)  # [S, 6, 3]
  off = rel - (rel @ d)[..., None] * d
  a, b = (np.asarray(v, np.float64) for v in cones.perpendicular_basis(direction))
  phi = np.arctan2(off @ b, off @ a)  # [S, 6]: HEXAGON (or its reverse) + turn
  wrap = lambda x: np.angle(np.exp(1j * x))  # to (-pi, pi]
  spread = lambda order: np.max(np.abs(wrap(phi - order - (phi[:, :1] - order[0]))), axis=-1)
  mirrored = spread(cones.HEXAGON[::-1]) < 1e-3
  assert np.all(mirrored != (spread(cones.HEXAGON) < 1e-3))  # each one or the other
  first = np.where(mirrored, cones.HEXAGON[::-1][0], cones.HEXAGON[0])
  turn = np.mod(phi[:, 0] - first, 2 * np.pi)
  low = turn < np.pi
  for given in (low, ~low, np.ones(num, bool)):
    n = np.sum(given)
    assert n > num // 3
    assert abs(np.mean(mirrored[given]) - 0.5) < 5 * np.sqrt(0.25 / n), (n, np.mean(
        mirrored[given]))
  assert abs(np.mean(low) - 0.5) < 5 * np.sqrt(0.25 / num)  # the turn uniform on [0, 2 pi)
