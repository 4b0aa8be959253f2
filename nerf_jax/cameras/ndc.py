"""Normalised device coordinates (NDC) for forward-facing scenes.

A forward-facing capture (LLFF, the built-in 'forward' scene) has every camera near the world
origin looking down world -z (`nerf_jax.cameras.rays` conventions) at content that extends from
z = -near to very far away. NDC squeezes that unbounded frustum into the cube [-1, 1]^3 with the
perspective projection of the reference camera (at the origin, focal fx, fy in pixels, image
width x height, centred principal point):

  x_ndc = -(2 fx / width) x / z,   y_ndc = -(2 fy / height) y / z,   z_ndc = 1 + 2 near / z.

The plane z = -near maps to z_ndc = -1 and z -> -inf to z_ndc -> +1; the image borders map to
x_ndc, y_ndc = +-1. A projective map sends lines to lines, so each world ray becomes an NDC ray:
first slide the origin along the ray onto the near plane,
  o <- o + t_n d,   t_n = -(near + o_z) / d_z      (now o_z = -near);
then the world point o + t d (t >= 0) maps to o' + s d' with
  o' = (-(2 fx / width) o_x / o_z,  -(2 fy / height) o_y / o_z,  1 + 2 near / o_z = -1),
  d' = (-(2 fx / width) (d_x / d_z - o_x / o_z),  -(2 fy / height) (d_y / d_z - o_y / o_z),
        -2 near / o_z = 2),
  s  = t d_z / (o_z + t d_z) = 1 - near / depth,    depth = -(o_z + t d_z)
(depth in front of the plane z = 0, which is a camera's z-depth when it sits on that plane looking
down -z). Substitute to check: o'_x + s d'_x = -(2 fx / width) (o_x + t d_x) / (o_z + t d_z).
An off-centre principal point only shifts x_ndc, y_ndc; the formulas assume a centred one.

So s in [0, 1) covers depths from near to infinity, and s is linear in disparity 1 / depth.
Render in NDC by sampling s uniformly in [near, far] = [0, 1] (not lindisp: uniform s already is
uniform in disparity), using `focal` = the training images' fx in pixels and `near` = a plane in
front of all content (1 after LLFF's bd_factor rescaling). Depth along NDC rays converts back
with depth = near / (1 - s). View directions for the MLP should come from the world rays.
"""

import jax.numpy as jnp

# |d_z| below this is treated as -_MIN_DZ: see `ndc_rays`.
_MIN_DZ = 1e-6


def ndc_rays(origins, directions, focal, width, height, near=1.0, focal_y=None):
  """World rays -> NDC rays (see the module docstring for the formulas).

  origins: float32 [..., 3], ray origins in world space (the reference camera frame).
  directions: float32 [..., 3], un-normalised directions; forward rays have d_z < 0.
  focal: float, fx in pixels. width, height: int or float, image size in pixels.
  near: float > 0, the world plane z = -near that becomes z_ndc = -1.
  focal_y: float or None, fy in pixels (None = focal).
  Returns (origins_ndc, directions_ndc): float32 [..., 3] each; directions_ndc has z = 2, so the
  NDC ray parameter s in [0, 1] spans z_ndc in [-1, 1].

  Rays with d_z = 0 run parallel to the near plane and never enter a forward-facing frustum; the
  shift t_n and d / d_z would be infinite. |d_z| is clamped to 1e-6 (with the forward sign) before
  dividing, so such rays get large but finite NDC rays (and finite gradients: the clamp happens
  before the division, not in a `where` after it). Rays with d_z > 0 point away from the scene;
  their NDC rays are finite but meaningless.
  """
  origins = jnp.asarray(origins, jnp.float32)
  directions = jnp.asarray(directions, jnp.float32)
  fy = focal if focal_y is None else focal_y
  scale_x, scale_y = -2.0 * focal / width, -2.0 * fy / height

  d_x, d_y, d_z = directions[..., 0], directions[..., 1], directions[..., 2]
  d_z = jnp.where(jnp.abs(d_z) < _MIN_DZ, -_MIN_DZ, d_z)
  t_n = -(near + origins[..., 2]) / d_z
  o_x = origins[..., 0] + t_n * d_x
  o_y = origins[..., 1] + t_n * d_y
  o_z = -near  # exactly, rather than o_z + t_n d_z with its rounding error

  origins_ndc = jnp.stack([scale_x * o_x / o_z, scale_y * o_y / o_z,
                           jnp.full_like(o_x, -1.0)], axis=-1)  # 1 + 2 near / o_z
  directions_ndc = jnp.stack([scale_x * (d_x / d_z - o_x / o_z), scale_y * (d_y / d_z - o_y / o_z),
                              jnp.full_like(o_x, 2.0)], axis=-1)  # -2 near / o_z
  return origins_ndc, directions_ndc
