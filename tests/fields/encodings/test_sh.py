"""encodings/sh.py against the defining properties of the real spherical
harmonics, each computed here independently: orthonormality over the sphere (an exact product
quadrature), the addition theorem per band, parity, and the count per band; each feature, sign
and order included, against a table of Cartesian polynomials written here (itself checked
against scipy's complex harmonics); and the Field's 'sh' direction encoding wired through
config, network and checkpoint signature.

The convention (instant-ngp's, plenoxels' and nerfacto's, `sh_enc` in tiny-cuda-nn): feature
l² + l + m is the real harmonic Y_lm, m = -l .. l, built from the complex Y_l^m *with* the
Condon-Shortley phase (-1)^m (scipy's `sph_harm_y`, polar angle θ from +z, azimuth φ from +x):
  Y_lm = sqrt(2)·Im Y_l^|m|  (m < 0),   Y_l^0  (m = 0),   sqrt(2)·Re Y_l^m  (m > 0),
so Y_1,-1 = -sqrt(3/4π)·y, Y_10 = +sqrt(3/4π)·z, Y_11 = -sqrt(3/4π)·x (odd |m|: negative
leading sign; the Wikipedia table, which drops the phase, has + there).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.fields import registry
from nerf_jax.fields.encodings import sh
from nerf_jax.run import builders, signature
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


def _sh_table(x, y, z):
  """The real harmonics of bands 0 .. 4 at unit (x, y, z) (float64 [...] each), band after
  band, m = -l .. l: [25] arrays [...]. Closed forms with their normalisations written as
  square roots; the signs are the Condon-Shortley phase's (module docstring)."""
  pi, s = math.pi, math.sqrt
  xx, yy, zz = x * x, y * y, z * z
  return [
      0.5 * s(1 / pi) + 0 * x,                                        # l = 0
      -s(3 / (4 * pi)) * y, s(3 / (4 * pi)) * z, -s(3 / (4 * pi)) * x,  # l = 1
      0.5 * s(15 / pi) * x * y,                                       # l = 2, m = -2
      -0.5 * s(15 / pi) * y * z,
      0.25 * s(5 / pi) * (3 * zz - 1),
      -0.5 * s(15 / pi) * x * z,
      0.25 * s(15 / pi) * (xx - yy),
      -0.25 * s(35 / (2 * pi)) * y * (3 * xx - yy),                   # l = 3, m = -3
      0.5 * s(105 / pi) * x * y * z,
      -0.25 * s(21 / (2 * pi)) * y * (5 * zz - 1),
      0.25 * s(7 / pi) * z * (5 * zz - 3),
      -0.25 * s(21 / (2 * pi)) * x * (5 * zz - 1),
      0.25 * s(105 / pi) * z * (xx - yy),
      -0.25 * s(35 / (2 * pi)) * x * (xx - 3 * yy),
      0.75 * s(35 / pi) * x * y * (xx - yy),                          # l = 4, m = -4
      -0.75 * s(35 / (2 * pi)) * y * z * (3 * xx - yy),
      0.75 * s(5 / pi) * x * y * (7 * zz - 1),
      -0.75 * s(5 / (2 * pi)) * y * z * (7 * zz - 3),
      (3 / 16) * s(1 / pi) * (35 * zz * zz - 30 * zz + 3),
      -0.75 * s(5 / (2 * pi)) * x * z * (7 * zz - 3),
      (3 / 8) * s(5 / pi) * (xx - yy) * (7 * zz - 1),
      -0.75 * s(35 / (2 * pi)) * x * z * (xx - 3 * yy),
      (3 / 16) * s(35 / pi) * (xx * xx - 6 * xx * yy + yy * yy),
  ]


def test_each_feature_is_its_harmonic_of_the_table_sign_and_order_included():
  """Feature k = l² + l + m of the encoding against the table's entry k, one by one, at random
  directions (no symmetry: every coordinate nonzero and distinct): a flipped sign or two
  swapped features of any band fail here."""
  assert sh.MAX_DEGREE == 5  # the table covers bands 0 .. 4; a new band needs its rows here
  d = _random_directions(64, seed=3)
  got = np.asarray(sh.spherical_harmonics(jnp.asarray(d), sh.MAX_DEGREE), np.float64)
  x, y, z = (np.float64(d[:, k]) for k in range(3))
  for k, want in enumerate(_sh_table(x, y, z)):
    l = math.isqrt(k)
    np.testing.assert_allclose(got[:, k], want, rtol=2e-5, atol=2e-6,
                               err_msg=f"feature {k}: l = {l}, m = {k - l * l - l}")


def test_the_table_is_scipys_harmonics_with_the_condon_shortley_phase():
  """The table above against scipy's complex Y_l^m (which carry the phase (-1)^m), made real
  as the module docstring says: an independent check of the table's constants and signs."""
  special = pytest.importorskip("scipy.special")
  if not hasattr(special, "sph_harm_y"):
    pytest.skip("scipy < 1.15: no sph_harm_y")
  d = np.float64(_random_directions(32, seed=4))
  d /= np.linalg.norm(d, axis=-1, keepdims=True)  # unit in float64: the table assumes it
  theta, phi = np.arccos(d[:, 2]), np.arctan2(d[:, 1], d[:, 0])  # polar from +z, azimuth
  table = _sh_table(d[:, 0], d[:, 1], d[:, 2])
  for l in range(sh.MAX_DEGREE):
    for m in range(-l, l + 1):
      y = special.sph_harm_y(l, abs(m), theta, phi)
      want = (np.sqrt(2) * y.imag if m < 0 else y.real if m == 0 else np.sqrt(2) * y.real)
      np.testing.assert_allclose(table[l * l + l + m], want, atol=1e-12,
                                 err_msg=f"l = {l}, m = {m}")


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
  field = builders.make_field(config)
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
    builders.make_field(small_config({"dir_encoding": "spherical"}))
