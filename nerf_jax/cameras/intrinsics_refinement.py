"""Camera intrinsics refinement: a focal scale per training image and one radial lens, shared,
learnt with the field (NeRF--'s per-camera focal, SCNeRF's shared radial distortion).

Names and shapes:
  log_focal: float32 [N], s_i per training image: its focal is the stored one times exp(s_i)
    (zero = as given; a log so that the focal stays positive and a 3x zoom is a step of 1.1);
  k: float32 [2], (k1, k2) of the UNDISTORTION polynomial (below), shared by every image
    (zeros = a pinhole);
  params['intrinsics'] = {'log_focal': ..., 'k': ...} (run/signature.init_state).

The model. Pixel (i, j) of a stored image has the normalised coordinates of the stored camera,
x = (i + p - cx)/fx, y = -(j + p - cy)/fy (rays.py); through its own focal they are the
distorted coordinates
  x_d = x·exp(-s_i),  y_d = y·exp(-s_i)   (= (u - cx)/f_i),
and the ray goes through the undistorted point
  x_u = x_d·g,  y_u = y_d·g,  g = 1 + k1 r_d² + k2 r_d⁴,  r_d² = x_d² + y_d²,
direction (x_u, y_u, -1) in the camera (z-depth parameter, as every ray here).

Which (k1, k2): those of the undistortion polynomial, learnt directly, not Brown–Conrady's
forward ones (data/lens.py, COLMAP's: x_d = x_u (1 + k1 r_u² + k2 r_u⁴)). The two are inverses
to first order: a forward (k1, k2) is undistorted by (-k1, 3 k1² - k2) up to r⁶ terms, so a
barrel lens (forward k1 < 0) learns k1 > 0. Why: the closed form is exact for what it learns,
defined for every (k1, k2) and smooth in them. Inverting the forward model by a few fixed
Newton steps was tried: exact for a lens it can invert, but a pixel beyond the fold of a
barrel (k1 < 0 with k2 small, e.g. r_d > 0.65 for k1 = -0.35, k2 = 0, which gradient descent
passes through) has no ray, and from zeros a fit of the landmark's lens went there and stayed
(its error grew 2x). The price: two terms of the inverse do not follow a strong barrel over a
wide photo exactly (tests/cameras/test_intrinsics_refinement.py states what a fit reaches).

Zeros are today's rays bit for bit: exp(-0) = 1 and g = 1 + 0 exactly, each a product with the
stored coordinates. No square root of r² is taken, so every gradient is finite at zero and at
the principal point.
"""

import flax.struct
import jax.numpy as jnp

# Smallest Jacobian determinant of the undistortion map used for a ray's footprint: past its
# fold (a learnt k strongly negative, g (g + 2 r² g') <= 0) its square root would be NaN.
MIN_JACOBIAN = 1e-6


def initial(num_images):
  """params['intrinsics'] of no refinement: {'log_focal': float32 [N] zeros, 'k': float32 [2]
  zeros}."""
  return {"log_focal": jnp.zeros((num_images,), jnp.float32), "k": jnp.zeros((2,), jnp.float32)}


@flax.struct.dataclass
class Lens:
  """One ray's refined camera (or a batch's, over leading `...`).

  log_focal: float32 [...], its image's s_i. k: float32 [2], the shared (k1, k2)."""
  log_focal: jnp.ndarray
  k: jnp.ndarray

  def undistort(self, dirs):
    """The refined camera-space directions of the stored camera's `dirs` (float32 [..., 3],
    z = -1, rays._directions) and each one's radius scale: (float32 [..., 3] with z = -1,
    float32 [...]). The radius scale is how much the pixel's footprint (its base radius,
    rays.base_radius) grows: exp(-s) times the square root of the undistortion map's Jacobian
    determinant g (g + 2 r² g'), g' = dg/dr²; 1 exactly at zeros."""
    scale = jnp.exp(-self.log_focal)
    xd, yd = dirs[..., 0] * scale, dirs[..., 1] * scale
    r2 = xd * xd + yd * yd
    k1, k2 = self.k[..., 0], self.k[..., 1]
    g = 1.0 + r2 * (k1 + r2 * k2)
    slope = k1 + 2.0 * r2 * k2  # dg / d r²
    radius = scale * jnp.sqrt(jnp.maximum(g * (g + 2.0 * r2 * slope), MIN_JACOBIAN))
    return jnp.stack([xd * g, yd * g, dirs[..., 2]], axis=-1), radius


def lens_of(intrinsics, image):
  """The Lens of images `image` (int32 [...]) of params['intrinsics'] `intrinsics`."""
  return Lens(intrinsics["log_focal"][image],
              jnp.broadcast_to(intrinsics["k"], (*jnp.shape(image), 2)))


def focals(focal, intrinsics):
  """Each training image's refined focal float32 [N] (pixels) of the stored `focal`."""
  return focal * jnp.exp(intrinsics["log_focal"])
