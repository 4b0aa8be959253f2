"""encodings/spherical_harmonics.py against the defining properties of the real spherical
harmonics, each computed here independently: orthonormality over the sphere (an exact product
quadrature), the addition theorem per band, parity, and the count per band; and the Field's
'sh' direction encoding wired through config, network and checkpoint signature."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.fields import registry
from nerf_jax.fields.encodings import spherical_harmonics as sh
from nerf_jax.run import components, signature
from tests.helpers import small_config


def _sphere_quadrature(n_z=12, n_phi=24):
  """Nodes float64 [n_z·n_phi, 3] and weights [n_z·n_phi] integrating every polynomial of
  degree < min(2·n_z, n_phi) over the unit sphere exactly: Gauss-Legendre in z times the
  trapezoid rule in the azimuth (exact for trigonometric polynomials of degree < n_phi)."""
  z, wz = np.polynomial.legendre.leggauss(n_z)
  phi = 2 * np.pi * np.arange(n_phi) / n_phi
  r = np.sqrt(1 - z ** 2)
  nodes = np.stack([np.outer(r, np.cos(phi)), np.outer(r, np.sin(phi)),
                    np.outer(z, np.ones(n_phi))], axis=-1).reshape(-1, 3)
  return nodes, np.outer(wz, np.full(n_phi, 2 * np.pi / n_phi)).reshape(-1)


def _random_directions(count, seed=0):
  d = np.random.default_rng(seed).normal(size=(count, 3))
  return (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)


@pytest.mark.parametrize("degree", range(1, sh.MAX_DEGREE + 1))
def test_the_features_are_orthonormal_over_the_sphere(degree):
  nodes, weights = _sphere_quadrature()
  y = np.asarray(sh.spherical_harmonics(jnp.asarray(nodes, jnp.float32), degree), np.float64)
  assert y.shape == (len(nodes), degree ** 2)
  gram = y.T @ (weights[:, None] * y)  # the products have degree <= 8 < 24: exact
  np.testing.assert_allclose(gram, np.eye(degree ** 2), atol=2e-6)


def test_each_band_obeys_the_addition_theorem_and_parity():
  """Σ_m Y_lm(d)² = (2l + 1) / 4π at every direction (so each band spans a rotation-invariant
  space) and Y_l(-d) = (-1)^l Y_l(d): band l holds 2l + 1 features of parity l."""
  d = _random_directions(500)
  y = np.asarray(sh.spherical_harmonics(jnp.asarray(d), sh.MAX_DEGREE), np.float64)
  y_opposite = np.asarray(sh.spherical_harmonics(jnp.asarray(-d), sh.MAX_DEGREE), np.float64)
  for l in range(sh.MAX_DEGREE):
    band = slice(l * l, (l + 1) * (l + 1))
    np.testing.assert_allclose(np.sum(y[:, band] ** 2, axis=-1), (2 * l + 1) / (4 * np.pi),
                               rtol=1e-5)
    np.testing.assert_allclose(y_opposite[:, band], (-1) ** l * y[:, band], atol=1e-6)


def test_lower_degrees_are_prefixes_and_gradients_are_finite_at_the_poles():
  d = jnp.asarray(_random_directions(20, seed=1))
  full = sh.spherical_harmonics(d, 4)
  np.testing.assert_array_equal(sh.spherical_harmonics(d, 2), full[:, :4])
  poles = jnp.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
  grad = jax.jacobian(lambda v: sh.spherical_harmonics(v, 4))(poles)
  assert np.all(np.isfinite(np.asarray(grad)))


@pytest.mark.parametrize("degree", [0, sh.MAX_DEGREE + 1])
def test_a_degree_out_of_range_is_a_one_line_error(degree):
  with pytest.raises(ValueError, match="dir_encode_dims"):
    sh.spherical_harmonics(jnp.zeros((1, 3)), degree)


def test_a_field_with_sh_directions_feeds_degree_squared_features_and_records_it():
  config = small_config({"dir_encoding": "sh", "dir_encode_dims": 4,
                         "model.view_dependent": True})
  field = components.make_field(config)
  assert field.dir_width == 16
  params = field.init(jax.random.PRNGKey(0))
  assert params["view"]["kernel"].shape[0] == config.model.width + 16
  points = jnp.zeros((2, 3, 3))
  dirs = jnp.asarray(_random_directions(2, seed=2))
  rgb, sigma = field.query(params, points, dirs)
  rgb_flipped, sigma_flipped = field.query(params, points, -dirs)
  np.testing.assert_array_equal(sigma, sigma_flipped)  # density ignores the direction
  assert not np.allclose(rgb, rgb_flipped)  # colour does not
  assert signature.model_signature(config)["dir_encoding"] == "sh"
  assert "dir_encoding" not in signature.model_signature(small_config({}))  # as saved before


def test_an_unknown_direction_encoding_is_a_one_line_error():
  known = ", ".join(registry.DIRECTION_ENCODINGS.names())
  with pytest.raises(ValueError, match=f"config.dir_encoding must be one of {known} or a module "
                     "path, got 'spherical'"):
    components.make_field(small_config({"dir_encoding": "spherical"}))
