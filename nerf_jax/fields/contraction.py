"""Scene contractions: all of space mapped into a bounded box, and back (pure jax.numpy).

An unbounded scene (a real capture: a room, a garden, the sky) has content at any distance. A
contraction keeps an inner region about the origin as it is and squeezes everything outside it
into a shell, so that a bounded field (an MLP, a feature grid) can hold the whole scene:

  contract(x) = x                         if |x| <= 1,
                (2 - 1/|x|) x / |x|       otherwise,

applied to x / radius and scaled back by radius. Two norms |.|:
  'l2'   — mip-NeRF 360's: the inner ball of radius `radius` stays, the rest of space goes into
           the ball of radius 2·radius;
  'linf' — nerfacto's scene contraction with the L-infinity norm max_k |x_k|: the inner cube
           [-radius, radius]^3 stays, the rest goes into the cube [-2·radius, 2·radius]^3, which
           a grid over +-2·radius covers with no wasted corners.
Both are continuous, with a continuous first derivative across |x| = 1 in the radial direction
(d/dr (2 - 1/r) = 1 at r = 1), and map each ray from the origin to itself, monotonically.

Names and axes:
  points:     float32 [..., 3]  world positions (any magnitude, +-inf allowed)
  contracted: float32 [..., 3]  positions in the contracted space, |contracted| <= 2·radius
  radius:     float > 0         half-size of the inner region (ball or cube)
  kind:       'l2' or 'linf'

Numerics (float32):
  * x = 0: the L2 norm's derivative x/|x| is 0/0 there. The norm is only ever evaluated on the
    branch that uses it, through the 'double where' (a safe argument inside, the choice outside),
    so neither the value nor the gradient of the discarded branch is NaN.
  * large |x|: |x|^2 overflows float32 above |x| ~ 1.8e19; the L2 norm is computed as
    m·|x/m| with m = max_k |x_k| (the L-infinity norm, exact), which never overflows. At |x| =
    1e10 the value is the outer boundary to rounding (2 - 1e-10 rounds to 2) and the Jacobian is
    finite and small (~2/|x| across the ray, ~1/|x|^2 along it).
  * infinite coordinates: a point with an infinite coordinate is the point at infinity in the
    direction of its infinite coordinates (their signs; finite coordinates count as 0), and it
    maps onto the outer boundary, e.g. (inf, 5, -inf) -> 2·radius·(1, 0, -1)/|(1, 0, -1)|. Its
    gradient is 0 (no finite change of x moves it).
  * the inverse: 1/(2 - |c|) is infinite on the outer boundary; `uncontract` clamps |c| at
    MAX_CONTRACTED = 2 - 2^-22 (two float32 ulps below 2), so it is finite everywhere and returns
    points of norm at most radius·2^22 ~ 4.2e6·radius for boundary points (and beyond: clamped
    onto the boundary first). Float32 cannot invert better: contract rounds every |x| >
    ~2^24·radius onto the boundary, and a round trip at norm r loses ~r·1.2e-7 relative.
"""

import jax
import jax.numpy as jnp

from nerf_jax.backend import precision

KINDS = ("l2", "linf")

# Half-size of the contracted space in units of `radius`: every output lies within 2·radius.
OUTER = 2.0

# The largest contracted norm `uncontract` inverts (2 - 2^-22 is exact in float32): the inverse
# 1/(2 - |c|) is infinite at |c| = 2, so norms are clamped here; it gives |x| = 2^22·radius.
MAX_CONTRACTED = 2.0 - 2.0 ** -22


def _check(kind):
  if kind not in KINDS:
    raise ValueError(f"contraction kind {kind!r} is not one of {', '.join(KINDS)}")


def _at_infinity(x):
  """Replace points with an infinite coordinate by their direction at infinity.

  x: float32 [..., 3]. Returns (x, infinite): float32 [..., 3], finite where x has no NaN (a point
  with an infinite coordinate becomes the signs of its infinite coordinates, 0 elsewhere); and
  bool [...], which points were at infinity. The where's other branch is the input itself, so no
  arithmetic on inf reaches the backward pass (its gradient there is 0).
  """
  is_inf = jnp.isinf(x)
  infinite = jnp.any(is_inf, axis=-1)
  x = jnp.where(infinite[..., None], jnp.where(is_inf, jnp.sign(x), 0.0), x)
  return x, infinite


def _norm_and_direction(x, kind):
  """Norm (of `kind`) and unit direction of finite points, safe at 0 and for huge |x|.

  x: float32 [..., 3], finite. Returns (norm: float32 [...] >= 0; direction: float32 [..., 3],
  x / norm, or 0 where x = 0).
  """
  norm_inf = jnp.max(jnp.abs(x), axis=-1)  # the L-infinity norm, exact
  # XLA on CPU flushes subnormal numbers to 0, and divides as x·(1/m): for m > 8.5e37, 1/m is
  # subnormal and x/m would be 0. Scaling such points by 2^-64 (exact) keeps 1/m normal.
  scale = jnp.where(norm_inf > 2.0 ** 64, 2.0 ** -64, 1.0)
  m = norm_inf * scale
  # Double where: at x = 0, divide by 1 instead of 0 (the result is 0 either way, but 0/0 in the
  # discarded branch would give a NaN gradient).
  nonzero = m > 0.0
  safe_m = jnp.where(nonzero, m, 1.0)
  u = x * scale[..., None] / safe_m[..., None]  # max_k |u_k| = 1 (or u = 0): no overflow below
  # The largest components are +-1 exactly, not m/m: an approximate division (GPUs) can round
  # m/m to 1 + 2^-23, and the linf contraction would then leave its cube. Where x = 0, sign = 0.
  u = jnp.where(jnp.abs(x) == norm_inf[..., None], jnp.sign(x), u)
  if kind == "linf":
    return norm_inf, u
  s = jnp.sum(u * u, axis=-1)
  # s >= 1 wherever x != 0; the safe value keeps sqrt away from 0, whose derivative is infinite.
  length = jnp.sqrt(jnp.where(nonzero, s, 1.0))
  # May overflow to inf for |x| > 3.4e38 / sqrt(3): then 1/norm = 0, the outer boundary.
  return norm_inf * length, u / length[..., None]


def contract(points, radius=1.0, kind="l2"):
  """Contract all of space into the ball ('l2') or cube ('linf') of half-size 2·radius.

  points: float32 [..., 3], world positions (+-inf allowed: see the module doc).
  radius: float > 0, half-size of the inner region, which is left unchanged. kind: 'l2' or 'linf'.
  Returns float32 [..., 3], of norm <= 2·radius (of `kind`); inside the inner region the points
  themselves, outside it (2 - 1/n)·radius·x/n with n = |x|/radius.
  """
  _check(kind)
  points = jnp.asarray(points, jnp.float32)
  x, infinite = _at_infinity(points)
  norm, _ = _norm_and_direction(jax.lax.stop_gradient(x), kind)
  # In world units, with no division: points / radius rounded by an approximate division (GPUs)
  # would put a point on the inner boundary outside it.
  outside = infinite | (norm > radius)
  # Double where: the squeezed branch is evaluated at a point outside where the point is inside
  # (the norm's gradient divides by |x|^2, which underflows to 0 for tiny |x|: a NaN gradient
  # at (1e-30, 0, 0) though the branch is discarded). Outside, the same ops on the same x.
  x = jnp.where(outside[..., None], x, jnp.float32([2.0 * radius, 0.0, 0.0]))
  norm, direction = _norm_and_direction(x, kind)
  # Double where: radius/norm only where norm > radius (a division by 0 at the origin would
  # poison the gradient). At infinity it is 0: the point lands on the outer boundary.
  inv_norm = jnp.where(infinite, 0.0, radius / jnp.where(outside, norm, radius))
  squeezed = radius * (OUTER - inv_norm)[..., None] * direction
  return jnp.where(outside[..., None], squeezed, points)  # inside, the points themselves


def uncontract(contracted, radius=1.0, kind="l2"):
  """The inverse of `contract`: contracted positions back to world positions.

  contracted: float32 [..., 3], of norm (of `kind`) at most 2·radius; norms beyond
  MAX_CONTRACTED·radius (the outer boundary, and anything outside it) are clamped to it.
  radius: float > 0. kind: 'l2' or 'linf'.
  Returns float32 [..., 3], finite, of norm at most 2^22·radius; exact inverse (to rounding) of
  `contract` for norms below MAX_CONTRACTED·radius.
  """
  _check(kind)
  contracted = jnp.asarray(contracted, jnp.float32)
  norm, direction = _norm_and_direction(contracted / radius, kind)
  outside = norm > 1.0
  # Clamped below 2 so that 2 - norm > 0 (exact subtraction near 2): the inverse stays finite.
  norm = jnp.minimum(norm, MAX_CONTRACTED)
  # Double where: the division only sees norms in (1, MAX_CONTRACTED] (2 - 1 = 1 elsewhere).
  world_norm = 1.0 / (OUTER - jnp.where(outside, norm, 1.0))
  return jnp.where(outside[..., None], radius * world_norm[..., None] * direction, contracted)


def inner_exit(origins, directions, radius=1.0, kind="l2"):
  """Where each ray leaves the inner region (the ball or cube of half-size `radius`).

  origins, directions: float32 [..., 3] (directions un-normalised, so t is in their units: z-depth
  for camera rays). radius: float > 0. kind: 'l2' (ball) or 'linf' (cube).
  Returns t_exit: float32 [...], the ray parameter at which the line leaves the region (it may be
  negative: behind the origin), or 0 for a line that misses the region.
  `spacing.stratified_unbounded` clamps it into [near, far].
  """
  _check(kind)
  o = jnp.asarray(origins, jnp.float32)
  d = jnp.asarray(directions, jnp.float32)
  if kind == "linf":
    # Slab method; a zero component divides by a tiny signed number (the slab bounds become
    # +-huge, as for a ray parallel to that slab) instead of 0.
    safe = jnp.where(jnp.abs(d) < 1e-12, jnp.where(d < 0, -1e-12, 1e-12), d)
    t1, t2 = (-radius - o) / safe, (radius - o) / safe
    t_enter = jnp.max(jnp.minimum(t1, t2), axis=-1)
    t_exit = jnp.min(jnp.maximum(t1, t2), axis=-1)
    return jnp.where(t_enter <= t_exit, t_exit, 0.0)
  # About the point of closest approach q = o + t0 d: the textbook quadratic b^2 - ac cancels
  # when the ray passes far from the ball's centre (as in scenes/raycast.py).
  dd = jnp.sum(d * d, axis=-1)
  safe_dd = jnp.where(dd > 0.0, dd, 1.0)  # a zero direction never leaves: treated as a miss
  t0 = -jnp.sum(o * d, axis=-1) / safe_dd
  q = o + t0[..., None] * d
  half2 = (radius ** 2 - jnp.sum(q * q, axis=-1)) / safe_dd
  hit = (half2 >= 0.0) & (dd > 0.0)
  return jnp.where(hit, t0 + jnp.sqrt(jnp.where(hit, half2, 0.0)), 0.0)


# Gaussians through the contraction (mip-NeRF 360, Barron et al. 2022, eq. 8-9): a Gaussian
# N(mean, cov) maps to N(contract(mean), J cov Jᵀ), J the Jacobian of `contract` at the mean
# (a linearisation: exact for the inner region, where contract is the identity and J = I).
#   mean: float32 [..., 3]; cov: float32 [..., 3, 3];
#   std: float32 [...] (an isotropic Gaussian's standard deviation).
# Numerics: J is finite everywhere (see the module doc: ~2/|x| across the ray and ~1/|x|^2 along
# it at large |x|, 0 at infinity), and so are its derivatives, which the gradients of J cov Jᵀ
# w.r.t. the mean need: inside the inner region J = I is not differentiated at all (a double
# where: contract's second derivative at tiny |x| is inf·0). J cov Jᵀ is positive
# semi-definite as cov is; float32 rounding may leave eigenvalues ~1e-7·(the largest) below 0
# (as for cov itself), and the result is symmetrised so that eigh sees a symmetric matrix.


def _inside(points, radius, kind):
  """bool [...]: whether points float32 [..., 3] lie in the inner region: `contract`'s own test
  (same norm, same comparison), so the two agree to the last bit on the boundary.

  A mask only: no gradient is taken through it (stop_gradient), so the norm's derivative, NaN
  at tiny |x|, is never formed.
  """
  x, infinite = _at_infinity(jax.lax.stop_gradient(jnp.asarray(points, jnp.float32)))
  norm, _ = _norm_and_direction(x, kind)
  return ~(infinite | (norm > radius))


def _contract_outside(points, inside, radius, kind):
  """contract(points), bit for bit, with contract evaluated only at points outside.

  points: float32 [..., 3]. inside: bool [...] (`_inside`). Double where: contract's own
  gradient is NaN at tiny non-zero points (|x| below ~1e-19: its norm's derivative divides by
  |x|^2, which underflows); inside, contract is the identity, so the points themselves are its
  value, and a point outside stands in for them in the discarded branch.
  """
  safe = jnp.where(inside[..., None], jnp.float32([2.0 * radius, 0.0, 0.0]), points)
  return jnp.where(inside[..., None], points, contract(safe, radius, kind))


def contraction_jacobian(points, radius=1.0, kind="l2"):
  """The Jacobian of `contract` at each point, by forward-mode differentiation.

  points: float32 [..., 3], finite. radius: float > 0. kind: 'l2' or 'linf'.
  Returns float32 [..., 3, 3], J[..., i, j] = d contract_i / d x_j; the identity inside the
  inner region.
  """
  _check(kind)
  points = jnp.asarray(points, jnp.float32)
  single = jax.jacfwd(lambda x: contract(x, radius, kind))
  # Double where: inside, J = I exactly, and the Jacobian is taken at a point outside instead.
  # contract's derivative divides by the norm m, its second derivative (what a gradient of J
  # needs) by m^2: inf·0 = NaN for a point like (1e-30, 0, 0), whose m^2 underflows.
  inside = _inside(points, radius, kind)
  safe = jnp.where(inside[..., None], jnp.float32([2.0 * radius, 0.0, 0.0]), points)
  jac = jnp.vectorize(single, signature="(n)->(n,n)")(safe)
  return jnp.where(inside[..., None, None], jnp.eye(3, dtype=jnp.float32), jac)


def contract_gaussian(mean, cov, radius=1.0, kind="l2"):
  """A Gaussian with full covariance through the contraction, linearised at its mean.

  mean: float32 [..., 3]. cov: float32 [..., 3, 3], positive semi-definite. radius, kind: as
  `contract`. Returns (contract(mean): float32 [..., 3], J cov Jᵀ: float32 [..., 3, 3]).
  """
  jac = contraction_jacobian(mean, radius, kind)
  # Full float32 (backend/precision.py): a TF32 product would perturb the small eigenvalues.
  out = precision.einsum("...ij,...jk,...lk->...il", jac, cov, jac)
  mean = _contract_outside(mean, _inside(mean, radius, kind), radius, kind)
  return mean, 0.5 * (out + jnp.swapaxes(out, -1, -2))


def contract_frustum_gaussian(mean, directions, t_var, r_var, radius=1.0, kind="l2"):
  """mip-NeRF 360's contracted Gaussian of a conical frustum, as the integrated encoding reads it.

  The frustum's full covariance (cameras/cones.lift_gaussian) is
    Σ = t_var·d dᵀ + r_var·(I - d dᵀ/|d|^2),
  its spread along the ray and across it; through the contraction it becomes J Σ Jᵀ (J at the
  mean, as `contract_gaussian`), and the integrated encoding reads its diagonal:
    diag(J Σ Jᵀ)_i = t_var·(J d)_i^2 + r_var·|P_i|^2,  P = J - (J d) dᵀ/|d|^2,
  P's rows those of J with their component along d removed (J times the projector across the
  ray, which is its own square). Both terms are sums of squares: >= 0 exactly, with no 3x3
  product formed and no matmul (elementwise float32, whatever the backend's matmul precision).

  mean: float32 [..., 3], the frustum's mean (world space). directions: float32 [..., 3], the
  ray's d (un-normalised; broadcast against mean). t_var, r_var: float32 [...], the variance of
  t along the ray and of the offset across it per axis (cones.frustum_moments, r_var already
  times radius^2), >= 0. radius, kind: as `contract`.
  Returns (contract(mean): float32 [..., 3], the diagonal of J Σ Jᵀ: float32 [..., 3], >= 0).

  Unlike (J∘J)·diag(Σ) (the form the field used before), this keeps Σ's off-diagonal terms: on a
  ray oblique to the axes, far outside the inner region, the long axis of a frustum's Gaussian
  (along the ray, nearly radial there) is squeezed by the radial ~1/|x|^2 of J, whereas its
  diagonal alone spreads that variance over every axis, to be squeezed only by the tangential
  ~1/|x| (tests/fields/test_contract_gaussians.py measures both against a Monte Carlo).
  """
  jac = contraction_jacobian(mean, radius, kind)  # [..., 3, 3], finite (see above)
  d = jnp.broadcast_to(jnp.asarray(directions, jnp.float32), jac.shape[:-1])
  jd = jnp.sum(jac * d[..., None, :], axis=-1)  # J d: [..., 3]
  d_sq = jnp.sum(d * d, axis=-1)
  # A zero direction has no axis: a double where divides by 1 there (P = J, the Gaussian
  # isotropic, as lift_gaussian makes it) instead of by 0, whose gradient would be inf·0 = NaN.
  d_sq = jnp.where(d_sq > 1e-18, d_sq, 1.0)  # cones.TINY_SQUARE (lengths below ~1e-9)
  across = jac - jd[..., :, None] * (d / d_sq[..., None])[..., None, :]  # P: [..., 3, 3]
  var = (t_var[..., None] * jd * jd
         + r_var[..., None] * jnp.sum(across * across, axis=-1))
  mean = _contract_outside(mean, _inside(mean, radius, kind), radius, kind)
  return mean, var


def contract_isotropic(mean, std, radius=1.0, kind="l2"):
  """An isotropic Gaussian through the contraction, kept isotropic (Zip-NeRF's scales).

  mean: float32 [..., 3]. std: float32 [...], its standard deviation. radius, kind: as
  `contract`. Returns (contract(mean): float32 [..., 3], std·|det J|^(1/3): float32 [...]): the
  scale that keeps the Gaussian's volume (the geometric mean of J's singular values), 0 at
  infinity.

  The closed form, for both kinds: outside, contract(x) = radius·g(n)·x/radius with n =
  |x|/radius (norm of `kind`) and g(n) = (2 - 1/n)/n, so J = g·I + g'(n)·x·(dn/dx)ᵀ, and
  det J = g^2·(g + n·g') (dn/dx · x = n for any norm, homogeneous of degree 1) = g^2/n^2, i.e.
  |det J|^(1/3) = (2 - 1/n)^(2/3)·n^(-4/3). The determinant of jacfwd's J in float32 would
  cancel: at |x| = 1e6 its radial factor 1/n^2 is 1e-6 of the others, and det's rounding is
  ~1e-7 of their product.
  """
  _check(kind)
  mean = jnp.asarray(mean, jnp.float32)
  # Double where: the norm (and the logs) only of points outside the inner region; inside the
  # scale is 1, and the norm's derivative at tiny |x| (1/|x|^2 in _norm_and_direction's
  # gradient) would be inf·0 = NaN.
  inside = _inside(mean, radius, kind)
  x, infinite = _at_infinity(jnp.where(inside[..., None], 2.0 * radius, mean))
  norm, _ = _norm_and_direction(x, kind)
  # n = inf (|x| > 3.4e38) gives exp(-inf) = 0, whose gradient is 0; points at infinity: 0.
  n = jnp.where(infinite, 2.0, norm / radius)
  log_scale = (2.0 / 3.0) * jnp.log(OUTER - 1.0 / n) - (4.0 / 3.0) * jnp.log(n)
  scale = jnp.where(infinite, 0.0, jnp.where(inside, 1.0, jnp.exp(log_scale)))
  return _contract_outside(mean, inside, radius, kind), std * scale
