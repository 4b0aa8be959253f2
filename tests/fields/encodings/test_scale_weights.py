"""Tests of nerf_jax.fields.encodings.scale_weights against references written here, and of
the cell sizes the lattices weigh their levels by over a box that is not a cube (model.grid_box,
model.grid_cell_aspect), read off the lattice's own shape here.

jax_debug_nans is on for the whole module: a NaN anywhere, a backward pass included, fails.
"""

import math

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.fields import contraction
from nerf_jax.fields.encodings import grid, scale_weights
from nerf_jax.fields.encodings import hash as hashgrid

pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: NaNs raise in this module


def test_weights_are_the_mass_of_the_gaussian_within_a_cell():
  """Against a Monte Carlo of N(0, std^2) samples within ±h/2 (5 standard errors), and the
  closed form in float64 with math.erf."""
  rng = np.random.default_rng(0)
  h = scale_weights.cell_sizes([16, 32, 64, 128, 512], 2.0)  # a box of side 2 (bound 1)
  std = np.float32([1e-3, 0.01, 0.03, 0.1, 0.3])
  w = np.asarray(scale_weights.level_weights(std, h))
  assert w.shape == (5, 5)
  x = rng.normal(size=(200_000, 5, 1)) * std[:, None]
  frac = np.mean(np.abs(x) < h / 2, axis=0)
  err = 5 * np.sqrt(frac * (1 - frac) / len(x)) + 1e-6
  np.testing.assert_array_less(np.abs(w - frac), err)
  ref = np.vectorize(math.erf)(h / (np.sqrt(8) * np.float64(std)[:, None]))
  np.testing.assert_allclose(w, ref, rtol=1e-6, atol=1e-7)


def test_cell_sizes_follow_the_grids_lattice_and_unit_box_form():
  """grid.py's convention, brute force: a point moved by one cell (side/(R - 1) in world units)
  lands in the next cell of `lower_corner`; and the world form equals Zip-NeRF's unit-box form
  erf(1/sqrt(8 std_u^2 n^2)), std_u = std/side, n = R - 1 cells."""
  bound = 1.3
  resolutions = hashgrid.level_resolutions(8, 16, 512)
  h = scale_weights.cell_sizes(resolutions, 2 * bound)
  for r, size in zip(resolutions, h):
    p = jnp.float32([[-0.377, 0.212, 0.05]])
    moved = p + jnp.float32([size, 0.0, 0.0])
    i0, f0 = grid.lower_corner(grid.to_unit_cube(p, bound), r)
    i1, f1 = grid.lower_corner(grid.to_unit_cube(moved, bound), r)
    assert int(i1[0, 0]) - int(i0[0, 0]) == 1 and abs(float(f1[0, 0] - f0[0, 0])) < 1e-3
  std = np.float32([0.0, 1e-4, 3e-3, 0.05, 1.0])
  unit_std = std / (2 * bound)
  n = np.float64(resolutions) - 1
  with np.errstate(divide="ignore"):
    ref = np.vectorize(math.erf)(1 / np.sqrt(8 * unit_std[:, None] ** 2 * n ** 2))
  np.testing.assert_allclose(scale_weights.level_weights(std, h), ref, rtol=1e-5, atol=1e-7)
  with pytest.raises(ValueError):
    scale_weights.cell_sizes([1, 4], 1.0)


def test_limits_and_gradients():
  h = scale_weights.cell_sizes([4, 16, 64, 256, 1024, 4096], 1.0)
  std = jnp.float32([0.0, 1e-30, 1e-12, 1e-3, 1.0, 1e10, 1e30, np.inf])
  w = np.asarray(scale_weights.level_weights(std, h))
  np.testing.assert_array_equal(w[:3], 1.0)  # points read every level fully
  np.testing.assert_array_equal(w[-1], 0.0)  # infinitely wide: nothing
  assert np.all(w[-3] < 1e-9) and np.all((w >= 0) & (w <= 1))
  assert np.all(np.diff(w, axis=0) <= 0) and np.all(np.diff(w, axis=1) <= 0)  # monotone
  sweep = jnp.concatenate([std, jnp.float32(10.0 ** np.linspace(-38, 38, 300))])
  grad = jax.grad(lambda s: jnp.sum(scale_weights.level_weights(s, h)))(sweep)
  assert np.all(np.isfinite(grad)) and np.all(grad <= 0.0)
  np.testing.assert_array_equal(grad[:3], 0.0)  # erf is flat (exactly 1) there
  # The gradient against the closed form -h/(sqrt(2 pi) std^2) exp(-h^2/(8 std^2)), summed.
  s = np.float64([1e-3, 1e-2, 0.1])
  ref = np.sum(-h / (np.sqrt(2 * np.pi) * s[:, None] ** 2)
               * np.exp(-h ** 2 / (8 * s[:, None] ** 2)), axis=1)
  got = jax.grad(lambda s: jnp.sum(scale_weights.level_weights(s, h)))(jnp.float32(s))
  np.testing.assert_allclose(got, ref, rtol=1e-4)


def random_covariances(seed, num=200):
  """float32 [num, 3, 3] PSD: A Aᵀ, A's scale log-uniform over 1e-12..1e3; every 5th flat
  exactly (a zero third row of A, so a zero third row and column: det = 0 in float32 too)."""
  rng = np.random.default_rng(seed)
  a = rng.normal(size=(num, 3, 3)) * 10.0 ** rng.uniform(-12, 3, (num, 1, 1))
  a[::5, 2, :] = 0.0
  return np.float32(a @ np.swapaxes(a, -1, -2))


def test_isotropic_std_is_the_sixth_root_of_the_determinant():
  covs = random_covariances(0)
  got = np.asarray(scale_weights.isotropic_std(covs))
  c64 = np.asarray(covs, np.float64)
  det = np.linalg.det(c64)
  full = np.ones(len(covs), bool)
  full[::5] = False
  # det of the float32 input is rounded by ~eps·cond relative, its sixth root by a sixth.
  cond = np.linalg.cond(c64[full])
  rtol = 1e-5 + 4 * 2.0 ** -23 * cond / 6
  np.testing.assert_array_less(np.abs(got[full] / det[full] ** (1 / 6) - 1), rtol)
  # Flat ones: the floor, 1e-4·sqrt(largest variance) (MIN_FLATNESS^(1/3)), up to rounding.
  scale = np.sqrt(np.max(np.diagonal(c64, axis1=-2, axis2=-1), axis=-1))
  np.testing.assert_allclose(got[~full], 1e-4 * scale[~full], rtol=1e-5)
  assert float(scale_weights.isotropic_std(jnp.zeros((3, 3)))) == 0.0
  # Diagonal form: the geometric mean of the standard deviations.
  var = np.float32(10.0 ** np.random.default_rng(1).uniform(-20, -10, (100, 3)))
  np.testing.assert_allclose(scale_weights.isotropic_std_diagonal(var),
                             np.prod(np.float64(var), axis=-1) ** (1 / 6), rtol=1e-5)
  np.testing.assert_allclose(scale_weights.isotropic_std(var[..., None] * np.eye(3)),
                             scale_weights.isotropic_std_diagonal(var), rtol=1e-5)


def test_isotropic_std_gradients_are_finite():
  covs = jnp.concatenate([jnp.asarray(random_covariances(2, 50)), jnp.zeros((1, 3, 3)),
                          jnp.float32(np.diag([1.0, 0.0, 0.0]))[None]])
  g = jax.grad(lambda c: jnp.sum(scale_weights.isotropic_std(c)))(covs)
  assert np.all(np.isfinite(g))
  var = jnp.float32([[0, 0, 0], [1, 0, 0], [1e-38, 1e-20, 1e30], [1, 2, 3]])
  g = jax.grad(lambda v: jnp.sum(scale_weights.isotropic_std_diagonal(v)))(var)
  assert np.all(np.isfinite(g))


@pytest.mark.parametrize("kind", contraction.KINDS)
def test_scale_of_a_contracted_gaussian_is_the_contracted_scale(kind):
  """isotropic_std(J cov Jᵀ) = |det J|^(1/3)·isotropic_std(cov): the scale through
  contract_gaussian equals contract_isotropic's of the scale, for |x| <= 20. Further out J cov Jᵀ
  flattens (radial 1/|x|^2 against tangential 2/|x|), and its float32 value keeps ~eps·λmax in
  the thin direction: its det is rounding beyond |x| ~ 1e3. So a grid's scales go through
  contract_isotropic, not through the covariance."""
  rng = np.random.default_rng(3)
  v = rng.normal(size=(100, 3))
  means = np.float32(v / np.linalg.norm(v, axis=-1, keepdims=True)
                     * 10.0 ** rng.uniform(-1, np.log10(20), (100, 1)))
  a = (np.eye(3) + 0.3 * rng.normal(size=(100, 3, 3))) * 0.01  # well conditioned
  covs = np.float32(a @ np.swapaxes(a, -1, -2))
  _, contracted = contraction.contract_gaussian(means, covs, 1.0, kind)
  _, scale = contraction.contract_isotropic(means, scale_weights.isotropic_std(covs), 1.0, kind)
  np.testing.assert_allclose(scale_weights.isotropic_std(contracted), scale, rtol=2e-3)


# A box 2 × 4 × 1 (x, y, z): the longest side is y, the first axis x is neither longest nor
# shortest, so a cell size read along the wrong axis is off by 2 or 4.
BOX = (-1.0, -2.0, -0.5, 1.0, 2.0, 0.5)


class _Encode(nn.Module):
  """A lattice encoding's features of multisamples, its parameters this module's."""
  encoding: object

  @nn.compact
  def __call__(self, points, std):
    """points float32 [N, M, 3], std float32 [N, M] -> float32 [N, L·F]."""
    return self.encoding.features(self, points[:, 0], multisamples=(points, std))


def _weights_of_constant_lattice(encoding, features):
  """(std float32 [N, M], features float32 [N, L, F]) of `encoding` at random multisamples
  inside BOX, with every lattice value 1: each level's features are then its scale weights
  averaged over the M multisamples."""
  rng = np.random.default_rng(7)
  low, high = np.float32(BOX[:3]), np.float32(BOX[3:])
  points = jnp.asarray(low + (high - low) * rng.uniform(0.1, 0.9, (5, 6, 3)), jnp.float32)
  std = jnp.asarray(10.0 ** rng.uniform(-2.5, -0.3, (5, 6)), jnp.float32)
  module = _Encode(encoding)
  shapes = jax.eval_shape(module.init, jax.random.PRNGKey(0), points, std)
  ones = jax.tree_util.tree_map(lambda a: jnp.ones(a.shape, a.dtype), shapes)
  got = jax.jit(module.apply)(ones, points, std)
  return np.asarray(std), np.asarray(got).reshape(5, -1, features)


def _mean_erf_weights(std, cells):
  """float64 [N, L]: Zip-NeRF's erf(h_l / (sqrt(8)·std)) averaged over the M multisamples."""
  erf = np.vectorize(math.erf)
  return erf(np.float64(cells) / (np.sqrt(8.0) * np.float64(std)[..., None])).mean(axis=1)


@pytest.mark.parametrize("aspect,want_shapes,want_cells", [
    ((1.0, 1.0, 1.0), [(5, 9, 3), (9, 17, 5)], (0.5, 0.25)),  # cubic: y's 4/8 and 4/16
    # Cells 4× as long in y: x has the most cells (2/0.25 = 8, then 16), not the longest y.
    ((1.0, 4.0, 1.0), [(9, 5, 5), (17, 9, 9)], (0.25, 0.125)),
])
def test_dense_grid_over_a_box_weighs_levels_by_the_cell_of_its_axis_with_most_cells(
    aspect, want_shapes, want_cells):
  """DenseGrid over BOX with resolutions (9, 17): its lattices' shapes, written here, and each
  level's weight from the cell size along the axis with the most cells (grid.Space.cell_sizes),
  read here off the lattice itself: side / (points - 1) on that axis. With cubic cells it is
  every axis's cell."""
  settings = grid.Settings(resolutions=(9, 17), features=2, antialias=True)
  space = grid.Space(bound=1.5, box=BOX, cell_aspect=aspect)
  dense = grid.DenseGrid(settings, space)
  assert [space.shape(r) for r in settings.resolutions] == want_shapes
  sides = np.float64(BOX[3:]) - np.float64(BOX[:3])
  cells = []
  for shape in want_shapes:
    per_axis = sides / (np.float64(shape) - 1)  # the cell's side along x, y, z
    if aspect == (1.0, 1.0, 1.0):
      np.testing.assert_allclose(per_axis, per_axis[1])  # cubic
    cells.append(per_axis[int(np.argmax(shape))])  # the axis with most cells
  np.testing.assert_allclose(cells, want_cells)
  np.testing.assert_allclose(space.cell_sizes(settings.resolutions), cells, rtol=1e-7)
  std, got = _weights_of_constant_lattice(dense, settings.features)
  want = _mean_erf_weights(std, cells)
  np.testing.assert_allclose(got, np.repeat(want[..., None], 2, -1), rtol=1e-5, atol=1e-6)


def test_hash_grid_over_a_box_weighs_levels_by_its_coarsest_axis():
  """A hash grid puts R_l lattice points on every axis of BOX whatever its sides, so its cells
  are 2/(R-1) × 4/(R-1) × 1/(R-1): the weights use the longest, y's 4/(R-1) (the axis with most
  cells per unit of grid_cell_aspect, all equal here: Space.cell_sizes)."""
  settings = hashgrid.Settings(levels=3, log2_size=10, features=2, base_resolution=5,
                               max_resolution=17, antialias=True)
  assert settings.resolutions == (5, 9, 17)
  space = grid.Space(bound=1.5, box=BOX)
  cells = 4.0 / (np.float64(settings.resolutions) - 1)  # y's side over R - 1 cells
  np.testing.assert_allclose(space.cell_sizes(settings.resolutions), cells, rtol=1e-7)
  std, got = _weights_of_constant_lattice(hashgrid.HashGrid(settings, space), settings.features)
  want = _mean_erf_weights(std, cells)
  np.testing.assert_allclose(got, np.repeat(want[..., None], 2, -1), rtol=1e-5, atol=1e-6)
