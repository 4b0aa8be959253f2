"""Tests of nerf_jax.fields.contraction against the closed form (numpy float64, written here).

jax_debug_nans is on for the whole module: a NaN anywhere, a discarded `where` branch or a
backward pass included, fails the test.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.fields import contraction

KINDS = contraction.KINDS
RADIUS = 1.5
contract = jax.jit(contraction.contract, static_argnums=(1, 2))
uncontract = jax.jit(contraction.uncontract, static_argnums=(1, 2))
jacobian = jax.jit(jax.vmap(jax.jacfwd(contraction.contract), in_axes=(0, None, None)),
                   static_argnums=(1, 2))


pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: NaNs raise in this module


def _norm(x, kind):
  return (np.linalg.norm(x, axis=-1) if kind == "l2" else np.max(np.abs(x), axis=-1))


def _reference(x, radius, kind):
  """The closed form in float64: y = x / radius; y if |y| <= 1 else (2 - 1/|y|) y / |y|."""
  y = np.asarray(x, np.float64) / radius
  n = _norm(y, kind)[..., None]
  return radius * np.where(n <= 1.0, y, (2.0 - 1.0 / np.maximum(n, 1.0)) * y / np.maximum(n, 1.0))


def _random_points(seed, num=2000, low=-3.0, high=6.0):
  """float32 [num, 3]: random directions, norms log-uniform in [10^low, 10^high]·RADIUS."""
  rng = np.random.default_rng(seed)
  v = rng.normal(size=(num, 3))
  v /= np.linalg.norm(v, axis=-1, keepdims=True)
  return (v * RADIUS * 10.0 ** rng.uniform(low, high, (num, 1))).astype(np.float32)


@pytest.mark.parametrize("kind", KINDS)
def test_contract_matches_closed_form(kind):
  x = _random_points(0)
  inside = _norm(x, kind) <= RADIUS
  assert 300 < inside.sum() < 1700  # both branches are exercised
  np.testing.assert_allclose(contract(x, RADIUS, kind), _reference(x, RADIUS, kind),
                             rtol=1e-6, atol=1e-6)
  # Inside the inner region the points are unchanged, bit for bit.
  np.testing.assert_array_equal(np.asarray(contract(x, RADIUS, kind))[inside], x[inside])


@pytest.mark.parametrize("kind", KINDS)
def test_contracted_points_lie_in_the_outer_region(kind):
  huge = np.array([[1e10, 0, 0], [1e30, -1e30, 1e30], [3e38, 3e38, 3e38],
                   [np.inf, 5.0, -np.inf], [-np.inf, 0.0, 0.0]], np.float32)
  x = np.concatenate([_random_points(1, low=-1.0, high=12.0), huge])
  y = np.asarray(contract(x, RADIUS, kind))
  assert np.all(np.isfinite(y))
  assert np.all(_norm(y.astype(np.float64), kind) <= 2.0 * RADIUS * (1 + 1e-6))
  if kind == "linf":  # the cube the grids cover
    assert np.all(np.abs(y) <= 2.0 * RADIUS)


@pytest.mark.parametrize("kind", KINDS)
def test_infinite_points_land_on_the_outer_boundary(kind):
  # The direction of a point at infinity is that of its infinite coordinates.
  x = np.array([[np.inf, 5.0, -np.inf], [0.0, -np.inf, 1e30], [np.inf, np.inf, np.inf]],
               np.float32)
  direction = np.array([[1.0, 0.0, -1.0], [0.0, -1.0, 0.0], [1.0, 1.0, 1.0]])
  expected = 2.0 * RADIUS * direction / _norm(direction, kind)[:, None]
  np.testing.assert_allclose(contract(x, RADIUS, kind), expected, rtol=1e-6)
  np.testing.assert_array_equal(jacobian(x, RADIUS, kind), 0.0)  # no finite change moves it


@pytest.mark.parametrize("kind", KINDS)
def test_round_trip(kind):
  # World -> contracted -> world: float32 holds the contracted norm 2 - 1/n to ~1.2e-7, and
  # d n / d(2 - 1/n) = n^2, so the relative error grows like n·1.2e-7 (n in units of radius).
  x = _random_points(2, low=-3.0, high=3.0)
  back = np.asarray(uncontract(contract(x, RADIUS, kind), RADIUS, kind), np.float64)
  n = _norm(x.astype(np.float64), kind) / RADIUS
  error = _norm(back - x, kind) / _norm(x.astype(np.float64), kind)
  assert np.all(error <= 1e-6 + 1e-6 * n), np.max(error / (1e-6 + 1e-6 * n))
  # Contracted -> world -> contracted, strictly inside the outer boundary.
  c = _random_points(3, low=-3.0, high=np.log10(1.999))
  np.testing.assert_allclose(contract(uncontract(c, RADIUS, kind), RADIUS, kind), c,
                             rtol=0, atol=2e-6)


@pytest.mark.parametrize("kind", KINDS)
def test_inverse_is_finite_and_clamped_at_the_outer_boundary(kind):
  direction = np.array([[0.6, 0.0, -0.8], [1.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
  direction /= _norm(direction, kind)[:, None]
  for scale in (1.999, 2.0, 2.5, 1e30):  # inside the boundary, on it, beyond it
    c = (scale * RADIUS * direction).astype(np.float32)
    x = np.asarray(uncontract(c, RADIUS, kind), np.float64)
    assert np.all(np.isfinite(x))
    n = _norm(x, kind) / RADIUS
    assert np.all(n <= 2.0 ** 22 * (1 + 1e-6))
    np.testing.assert_allclose(x / (n[:, None] * RADIUS), direction, atol=1e-6)  # same direction
    if scale < 2.0:
      np.testing.assert_allclose(n, 1.0 / (2.0 - scale), rtol=1e-3)
    else:
      np.testing.assert_allclose(n, 2.0 ** 22, rtol=1e-6)
  jac = jax.jacfwd(contraction.uncontract)
  for c in (np.zeros(3), RADIUS * direction[0], 1.999 * RADIUS * direction[0],
            2.0 * RADIUS * direction[0]):
    assert np.all(np.isfinite(jac(jnp.asarray(c, jnp.float32), RADIUS, kind)))


@pytest.mark.parametrize("kind", KINDS)
def test_continuous_across_the_inner_boundary(kind):
  x = _random_points(4, num=200, low=0.0, high=0.0)  # norms exactly RADIUS (l2), directions
  x = x / _norm(x, kind)[:, None] * RADIUS
  below = contract((x * (1 - 1e-6)).astype(np.float32), RADIUS, kind)
  above = contract((x * (1 + 1e-6)).astype(np.float32), RADIUS, kind)
  np.testing.assert_allclose(below, above, rtol=0, atol=1e-5 * RADIUS)
  # The Jacobian is the identity on both sides: the contraction is C1 across the boundary
  # (d/dr (2 - 1/r) = 1 and (2 - 1/r)/r = 1 at r = 1).
  for side in (1 - 1e-5, 1 + 1e-5):
    jac = jacobian((x * side).astype(np.float32), RADIUS, kind)
    np.testing.assert_allclose(jac, np.broadcast_to(np.eye(3), jac.shape), atol=1e-4)


@pytest.mark.parametrize("kind", KINDS)
def test_monotone_along_rays(kind):
  rng = np.random.default_rng(5)
  v = rng.normal(size=(50, 1, 3))
  t = np.geomspace(1e-4, 1e8, 400)[None, :, None]  # steps of 7.5%: above float32 rounding
  # The norms of float32 outputs are known to their components' rounding, ~2 ulps of 2·RADIUS.
  rounding = 4.0 * 2.0 * RADIUS * 2.0 ** -24
  # Rays from the centre: the direction is kept and the contracted norm increases.
  y = np.asarray(contract((v * t).astype(np.float32), RADIUS, kind), np.float64)
  n = _norm(y, kind)
  assert np.all(np.diff(n, axis=-1) >= -rounding)
  assert np.all(np.diff(n, axis=-1)[:, :200] > 0)  # strictly, until rounding reaches 2·RADIUS
  unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)
  np.testing.assert_allclose(unit(y), np.broadcast_to(unit(v), y.shape), atol=1e-6)
  # Camera rays o + t d (from before their closest approach to the centre): the contracted
  # norm rises and falls with the world norm; far along, the point tends to the boundary in the
  # direction d.
  o = rng.normal(size=(50, 1, 3)) * 3.0
  d = v
  t = np.concatenate([-t[:, ::-1], t], axis=1)
  points = o + t * d
  world = np.diff(_norm(points, kind), axis=-1)
  n = _norm(np.asarray(contract(points.astype(np.float32), RADIUS, kind), np.float64), kind)
  step = np.diff(n, axis=-1)
  assert np.all(step[world > 0] >= -rounding) and np.all(step[world < 0] <= rounding)
  far = np.asarray(contract((o + 1e8 * d).astype(np.float32), RADIUS, kind))[:, 0]
  expected = 2.0 * RADIUS * d[:, 0] / _norm(d[:, 0], kind)[:, None]
  np.testing.assert_allclose(far, expected, atol=1e-5)


def _reference_jacobian_l2(x, radius):
  """d contract / dx outside the ball: (2 - 1/n)/n (I - u u^T) + (1/n^2) u u^T, n = |x|/radius."""
  n = np.linalg.norm(x) / radius
  u = x / np.linalg.norm(x)
  return (2.0 - 1.0 / n) / n * (np.eye(3) - np.outer(u, u)) + np.outer(u, u) / n ** 2


@pytest.mark.parametrize("kind", KINDS)
def test_jacobian_finite_at_zero_boundary_and_far(kind):
  e = np.eye(3, dtype=np.float32)
  points = np.array([[0.0, 0.0, 0.0], RADIUS * e[0], -RADIUS * e[2], [1e8, 0.0, 0.0],
                     [3e7, -4e7, 1e6], [0.0, 1e10, 0.0]], np.float32)
  jac = np.asarray(jacobian(points, RADIUS, kind), np.float64)
  assert np.all(np.isfinite(jac))
  np.testing.assert_array_equal(jac[:3], np.broadcast_to(np.eye(3), (3, 3, 3)))  # inside: x
  # Far away: across the ray ~2/n, along it ~1/n^2 (n = |x|/radius), all finite.
  for x, j in zip(points[3:], jac[3:]):
    assert np.all(np.abs(j) <= 2.0 * RADIUS / np.max(np.abs(x)) * 2.0)
  # Against the closed form where it is smooth (axis points for L-infinity, any for L2).
  # The entries are known to float32 rounding of the largest one (~2/n): along the ray, 1/n^2 is
  # below that and comes out as rounding noise for 'linf' (a difference 1/m - x/m^2).
  atol = 1e-6 * 2.0 * RADIUS / 1e8
  np.testing.assert_allclose(jac[3], np.diag([RADIUS ** 2 / 1e16] + 2 * [2 * RADIUS / 1e8]),
                             rtol=1e-5, atol=atol)
  if kind == "l2":
    for x, j in zip(points[3:], jac[3:]):
      np.testing.assert_allclose(j, _reference_jacobian_l2(x.astype(np.float64), RADIUS),
                                 rtol=1e-5, atol=atol * 1e8 / np.linalg.norm(x))


@pytest.mark.parametrize("kind", KINDS)
def test_gradient_finite_at_tiny_nonzero_points(kind):
  # |x|^2 underflows for |x| < ~1e-19: the discarded outside branch's norm derivative used to
  # divide by it (a NaN gradient under debug_nans). Inside, contract is the identity: grad = 1.
  tiny = np.array([[1e-30, 0.0, 0.0], [0.0, -1e-25, 1e-38], [1e-20, 1e-20, 1e-20]], np.float32)
  grad = jax.jit(jax.grad(lambda x: jnp.sum(contraction.contract(x, RADIUS, kind))))(tiny)
  np.testing.assert_array_equal(np.asarray(grad), np.ones_like(tiny))
  np.testing.assert_array_equal(np.asarray(contract(tiny, RADIUS, kind)), tiny)


def test_jacobian_matches_finite_differences_outside():
  for kind in KINDS:
    x = _random_points(7, num=20, low=0.2, high=1.0).astype(np.float64)
    jac = np.asarray(jacobian(x.astype(np.float32), RADIUS, kind), np.float64)
    h = 1e-6
    for p, j in zip(x, jac):
      fd = np.stack([(_reference(p + h * e, RADIUS, kind) - _reference(p - h * e, RADIUS, kind))
                     / (2 * h) for e in np.eye(3)], -1)
      np.testing.assert_allclose(j, fd, atol=1e-5)


@pytest.mark.parametrize("kind", KINDS)
def test_inner_exit_matches_brute_force(kind):
  rng = np.random.default_rng(8)
  origins = rng.normal(size=(300, 3)) * 2.0
  directions = rng.normal(size=(300, 3))
  t_exit = np.asarray(contraction.inner_exit(origins.astype(np.float32),
                                             directions.astype(np.float32), RADIUS, kind))
  t = np.linspace(-20.0, 20.0, 40001)
  inside = _norm(origins[:, None] + t[None, :, None] * directions[:, None], kind) <= RADIUS
  hit = inside.any(-1)
  assert 50 < hit.sum() < 250
  last = np.where(hit, t[len(t) - 1 - np.argmax(inside[:, ::-1], -1)], 0.0)
  np.testing.assert_allclose(t_exit, last, atol=2e-3)  # the brute-force grid's step is 1e-3
  np.testing.assert_array_equal(t_exit[~hit], 0.0)
  on = origins[hit] + t_exit[hit, None] * directions[hit]
  np.testing.assert_allclose(_norm(on, kind), RADIUS, rtol=1e-5)


def test_unknown_kind():
  with pytest.raises(ValueError, match="l2, linf"):
    contraction.contract(np.zeros(3), 1.0, "l1")
  with pytest.raises(ValueError, match="l2, linf"):
    contraction.uncontract(np.zeros(3), 1.0, "sphere")
