"""Spherical-harmonics encoding of view directions (instant-ngp's and nerfacto's, degree 4;
config.dir_encoding = 'sh', its degree config.dir_encode_dims).

d: float32 [..., 3] unit directions (x, y, z). The encoding is the real spherical harmonics
Y_l^m(d) of bands l = 0 .. degree - 1, m = -l .. l in order: degree² features, an orthonormal
basis over the sphere (∫ Y_i Y_j dΩ = δ_ij) of the polynomials of degree < `degree` there.
Each band is written as its Cartesian polynomial (no angles, so no atan2 or acos whose
gradients blow up at the poles): every feature is bounded by sqrt((2l + 1) / 4π) <= 0.85 on
the sphere (the addition theorem: a band's squares sum to (2l + 1) / 4π), and smooth.

Degree 4 gives 16 features, where 4 frequency bands of a direction give 27. At equal steps on
a CPU it lost to the 4 bands by 0.07-0.12 dB (glossy, fox: docs/gpu.md), so no shipped config
uses it; it is here for instant-ngp-like setups and for comparison.
"""

import dataclasses

import jax.numpy as jnp

from nerf_jax.fields import protocol, registry

MAX_DEGREE = 5  # bands l = 0..4, 25 features


def _band(l, x, y, z):
  """The 2l + 1 real spherical harmonics of band l (m = -l .. l) at unit (x, y, z)."""
  if l == 0:
    return [jnp.full_like(x, 0.28209479177387814)]  # 1 / (2 sqrt(pi))
  if l == 1:
    c = 0.4886025119029199  # sqrt(3 / 4pi)
    return [-c * y, c * z, -c * x]
  xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
  if l == 2:
    return [1.0925484305920792 * xy, -1.0925484305920792 * yz,
            0.31539156525252005 * (3.0 * zz - 1.0), -1.0925484305920792 * xz,
            0.5462742152960396 * (xx - yy)]
  if l == 3:
    return [-0.5900435899266435 * y * (3.0 * xx - yy), 2.890611442640554 * xy * z,
            -0.4570457994644658 * y * (5.0 * zz - 1.0), 0.3731763325901154 * z * (5.0 * zz - 3.0),
            -0.4570457994644658 * x * (5.0 * zz - 1.0), 1.445305721320277 * z * (xx - yy),
            -0.5900435899266435 * x * (xx - 3.0 * yy)]
  return [2.5033429417967046 * xy * (xx - yy), -1.7701307697799304 * yz * (3.0 * xx - yy),
          0.9461746957575601 * xy * (7.0 * zz - 1.0), -0.6690465435572892 * yz * (7.0 * zz - 3.0),
          0.10578554691520431 * (35.0 * zz * zz - 30.0 * zz + 3.0),
          -0.6690465435572892 * xz * (7.0 * zz - 3.0),
          0.47308734787878004 * (xx - yy) * (7.0 * zz - 1.0),
          -1.7701307697799304 * xz * (xx - 3.0 * yy),
          0.6258357354491761 * (xx * (xx - 3.0 * yy) - yy * (3.0 * xx - yy))]


def spherical_harmonics(d, degree):
  """Real spherical harmonics of bands 0 .. degree - 1 at unit directions.

  d: float32 [..., 3] unit vectors. degree: int in 1 .. MAX_DEGREE.
  Returns float32 [..., degree²], band after band (module docstring).
  """
  if not 1 <= degree <= MAX_DEGREE:
    raise ValueError(f"spherical harmonics: dir_encode_dims (the degree) must be in 1.."
                     f"{MAX_DEGREE} with dir_encoding='sh', got {degree}")
  x, y, z = d[..., 0], d[..., 1], d[..., 2]
  features = [f for l in range(degree) for f in _band(l, x, y, z)]
  return jnp.stack(features, axis=-1).astype(d.dtype)


def encoded_width(degree):
  """Features of `spherical_harmonics` at `degree`: degree²."""
  return degree * degree


@dataclasses.dataclass(frozen=True)
class SphericalHarmonics:
  """The direction encoding of `degree` bands (protocol.Encoding): no parameters, nothing to
  open coarse to fine."""
  degree: int

  coarse_to_fine_stages = 0

  def band_weights(self, bands):
    del bands
    return None

  def features(self, module, x, weights=None):
    """`spherical_harmonics` of unit directions x float32 [..., 3] (module, weights: unused)."""
    del module, weights
    return spherical_harmonics(x, self.degree)

  def inside(self, points):
    del points
    return None

  def width(self, dim):
    del dim
    return encoded_width(self.degree)


def build(settings, shared):
  """The SphericalHarmonics of degree config.dir_encode_dims (protocol.DirectionSettings)."""
  del shared
  if not 1 <= settings.dir_encode_dims <= MAX_DEGREE:
    raise ValueError(f"spherical harmonics: dir_encode_dims (the degree) must be in 1.."
                     f"{MAX_DEGREE} with dir_encoding='sh', got {settings.dir_encode_dims}")
  return SphericalHarmonics(settings.dir_encode_dims)


DIRECTION_ENCODING = registry.Encoding("sh", protocol.DirectionSettings, build, section="")
