"""The proposal sampler (mip-NeRF 360, nerfacto) and its step-function math: the envelope's
bound, the interlevel loss, resampling; the sampler `ProposalSampler`, registered as
config.sampler = 'proposal' (samplers/registry.py), its settings `Settings` (config.proposal)
and its loss term `Interlevel`.

A proposal network predicts a cheap density along each ray. Its weights, a step function over its
own intervals (the envelope), place the samples of the next level (a finer proposal or the NeRF,
the target) and are trained to bound the target's weights. Names and axes, for rays [...]:

  t:     float32 [..., S + 1] sorted interval edges of the target; interval i is [t_i, t_{i+1}).
  w:     float32 [..., S] the target's weights >= 0 (compositing weights, sum <= 1).
  t_env: float32 [..., M + 1] sorted interval edges of the envelope (the proposal).
  w_env: float32 [..., M] the envelope's weights >= 0.

The leading axes [...] of t and of (t_env, w_env) broadcast against each other. Edges are finite
(the samplers cap far at spacing.MAX_FAR = 1e10); the bound and the loss only compare them.

Overlap, as in mip-NeRF 360's definition: intervals are half-open, [a, b), so they tile the ray, and
two intervals overlap iff their intersection is not empty. So intervals that only share an edge do
not overlap, and a zero-width interval is empty and overlaps nothing: the envelope's weight on one
counts nowhere, and a target interval of zero width is bounded by 0 (compositing gives such an
interval zero weight: alpha = 1 - exp(-sigma·0) = 0).

Numerics: all-zero weights give outer = 0, a loss of 0 and zero gradients, and resampling falls
back to evenly spread points (sample_pdf's padding); one-hot weights are no special case (no
logarithm or division by a weight); zero-width intervals are empty as above, and resampling
never divides by their width; huge distances (edges out to 1e10) are only compared by `outer` and
the loss, and resampling only averages two of them.
"""

import dataclasses
from typing import ClassVar, Tuple

import jax
import jax.numpy as jnp

from nerf_jax.backend import components
from nerf_jax.fields import density_field
from nerf_jax.samplers import placement, spacing
from nerf_jax.volume import quadrature

# The loss divides by w + _EPS. Any eps > 0 keeps it finite: the denominator is positive where
# w = 0 (where the numerator is 0 too, as outer >= 0), each term max(0, w - outer)²/(w + eps) is
# at most w and its gradient w.r.t. outer at most 2 in magnitude. 1e-7 is a normal float32 (a GPU
# flushes subnormals to 0) far below the weights that matter, where terms stay (w - outer)²/w.
_EPS = 1e-7


def outer(t, t_env, w_env):
  """The envelope's bound on each target interval: float32 [..., S].

  t: float32 [..., S + 1] sorted target edges. t_env: float32 [..., M + 1] sorted envelope edges.
  w_env: float32 [..., M] envelope weights >= 0. Entry i is the sum of w_env_j over the envelope
  intervals [t_env_j, t_env_{j+1}) that overlap [t_i, t_{i+1}) (see the module doc): mip-NeRF
  360's outer measure, an upper bound of any weight the same density puts on interval i.
  O((S + M) log M) per ray: two binary searches per target edge and a cumulative sum.
  """
  batch = jnp.broadcast_shapes(t.shape[:-1], t_env.shape[:-1], w_env.shape[:-1])
  t, t_env, w_env = (jnp.broadcast_to(a, (*batch, a.shape[-1])) for a in (t, t_env, w_env))
  # An empty envelope interval overlaps nothing: its weight counts nowhere.
  w_env = jnp.where(t_env[..., 1:] > t_env[..., :-1], w_env, 0.0)
  zero = jnp.zeros_like(w_env[..., :1])
  cum = jnp.concatenate([zero, jnp.cumsum(w_env, axis=-1)], axis=-1)  # sum of w_env_j, j < k
  # [e_j, e_{j+1}) overlaps [a, b) (a < b) iff e_j < b and e_{j+1} > a, i.e. for j in
  # [lo - 1, hi) with lo = #{e <= a}, hi = #{e < b}; clipped to [0, M), lo - 1 <= hi.
  lo = _count(t_env, t[..., :-1], "right")
  hi = _count(t_env, t[..., 1:], "left")
  first = jnp.maximum(lo - 1, 0)
  last = jnp.minimum(hi, w_env.shape[-1])
  total = _take(cum, last) - _take(cum, first)
  # >= 0 exactly; the clamp undoes rounding of a cumulative sum evaluated as a parallel scan. A
  # `where`, not jnp.maximum: at total = 0 (an empty envelope) the gradient stays 1, not 1/2.
  total = jnp.where(total < 0.0, 0.0, total)
  return jnp.where(t[..., 1:] > t[..., :-1], total, 0.0)


def _count(edges, x, side):
  """Per ray, how many edges [..., K] are < x (side 'left') or <= x ('right'): int [..., Q]."""
  flat_edges = edges.reshape(-1, edges.shape[-1])
  flat_x = x.reshape(-1, x.shape[-1])
  count = jax.vmap(lambda e, v: jnp.searchsorted(e, v, side=side))(flat_edges, flat_x)
  return count.reshape(x.shape)


def _take(a, idx):
  return jnp.take_along_axis(a, idx, axis=-1)


def interlevel_loss(t, w, t_env, w_env):
  """mip-NeRF 360's proposal loss per ray: float32 [...].

  t: float32 [..., S + 1] sorted target edges. w: float32 [..., S] target weights >= 0.
  t_env: float32 [..., M + 1] sorted envelope edges. w_env: float32 [..., M] envelope weights.
  Returns sum_i max(0, w_i - outer_i)² / (w_i + eps), outer = `outer(t, t_env, w_env)`: 0 where
  the envelope bounds the target everywhere. The target is under stop_gradient (only the envelope
  is trained by this loss); edges get no gradient anyway (they are only compared). Finite, with
  finite gradients, for any finite inputs of this form (see _EPS); a weight on a zero-width target
  interval adds the constant w²/(w + eps).
  """
  t = jax.lax.stop_gradient(t)
  w = jax.lax.stop_gradient(jnp.maximum(w, 0.0))  # >= 0 keeps w + eps >= eps
  excess = jnp.maximum(w - outer(t, t_env, w_env), 0.0)
  return jnp.sum(excess * excess / (w + _EPS), axis=-1)


# How `resample` draws with a key (Settings.resample): NeRF's sorted uniforms, or mip-NeRF 360's
# (and nerfacto's) evenly spaced grid shifted by one random offset per ray.
RESAMPLE_METHODS = ("sorted_uniform", "jittered_grid")


# The sampler.

@dataclasses.dataclass(frozen=True)
class Settings:
  """How the proposal levels sample (config.proposal; nerfacto's defaults). The levels' density
  fields are fields/density_field.py's (HashDensity, GridDensity), their lattice levels geometric
  from base_resolution to max_resolution (hashgrid.level_resolutions: one level is
  base_resolution). Validated on construction (ValueError naming the config field)."""
  num_samples: Tuple[int, ...] = (256, 96)  # samples per ray of each level (NeRF: num_samples)
  field: str = "hash"  # levels' density fields: 'hash' (nerfacto's) or 'grid' (dense, CPU)
  max_resolution: Tuple[int, ...] = (128, 256)  # finest lattice of each level's density field
  levels: int = 5  # lattice levels of each density field (one level: base_resolution)
  log2_size: int = 17  # 'hash': log2 of each level's rows
  features: int = 2  # features per lattice point (hash row)
  base_resolution: int = 16  # coarsest lattice
  hidden: int = 16  # units of the density fields' one hidden layer
  loss_weight: float = 1.0  # weight of the interlevel loss that trains the proposals (0: never)
  padding: float = 0.01  # weight added to every interval before resampling the next level
  resample: str = "sorted_uniform"  # 'sorted_uniform' (NeRF's) or 'jittered_grid' (mip-NeRF 360)

  def __post_init__(self):
    problem = _problem(self)
    if problem:
      raise ValueError(f"config.proposal.{problem}")


def resample(t, w, num_samples, key=None, padding=Settings.padding,
             method=Settings.resample):
  """The next level's edges, drawn from the step function (t, w): float32 [..., N + 1].

  t: float32 [..., S + 1] sorted edges. w: float32 [..., S] weights >= 0. num_samples: int N >= 1.
  key: PRNG key, or None for deterministic edges. padding: float, added to every non-empty
  interval's weight before normalising (`spacing.sample_pdf`; Settings.padding).
  method: how a key draws the points (RESAMPLE_METHODS; Settings.resample).
  Returns sorted edges with t_0 and t_S exactly at the ends, gradients stopped.

  N points are drawn with `spacing.sample_pdf` and the interior edges are the midpoints between
  consecutive points. Key None: the points at the quantiles (k + 1/2)/N, so an edge whose two
  points lie in one interval of (t, w) is at the quantile k/N. With a key, 'sorted_uniform'
  (NeRF's): N uniform draws, sorted, whose gaps (and so the new intervals' weights) vary about
  as much as their mean 1/N; 'jittered_grid' (mip-NeRF 360's, nerfacto's): the quantiles
  (k + δ)/N with one δ ~ U[0, 1) per ray, so every interior interval holds 1/N of the (padded)
  weight, as without a key (where its two points share an interval of (t, w); the first holds
  (1/2 + δ)/N, the last (3/2 - δ)/N). Zero-width intervals get no points (sample_pdf), all-zero
  weights give points evenly spread over the intervals (padding > 0) or over t (padding = 0).
  """
  if method not in RESAMPLE_METHODS:
    raise ValueError(f"resample method {method!r} is not one of {', '.join(RESAMPLE_METHODS)}")
  t = jax.lax.stop_gradient(t)
  points = spacing.sample_pdf(t, w, num_samples, key, padding,
                              jittered_grid=method == "jittered_grid")  # sorted, in [t_0, t_S]
  # 0.5·(a + b) lies in [a, b] for floats a <= b (rounding is monotone, halving a normal float is
  # exact, no overflow for edges <= 1e10), so the edges stay sorted and inside [t_0, t_S].
  inner = 0.5 * (points[..., 1:] + points[..., :-1])
  return jnp.concatenate([t[..., :1], inner, t[..., -1:]], axis=-1)


# The density fields a level may have (Settings.field).
FIELDS = ("hash", "grid")


def settings_from(section):
  """Settings of config.proposal, `section` a mapping of its fields; ValueError naming the
  field for an unknown field or a value that cannot work."""
  return components.settings_from(Settings, section, "proposal")


def _problem(s):
  """The first setting of `s` (Settings) that cannot work, as 'field=value: why', or None."""
  if not s.num_samples or min(s.num_samples) < 1:
    return f"num_samples={s.num_samples}: one count >= 1 per proposal level, e.g. (256, 96)"
  if s.field not in FIELDS:
    return f"field={s.field!r}: use one of {', '.join(map(repr, FIELDS))}"
  if s.resample not in RESAMPLE_METHODS:
    return f"resample={s.resample!r}: use one of {', '.join(map(repr, RESAMPLE_METHODS))}"
  if len(s.max_resolution) != len(s.num_samples):
    return (f"max_resolution={s.max_resolution}: one per proposal level "
            f"({len(s.num_samples)}, as num_samples)")
  checks = (("levels", s.levels >= 1, ">= 1"), ("log2_size", 1 <= s.log2_size <= 24, "in [1, 24]"),
            ("features", s.features >= 1, ">= 1"), ("hidden", s.hidden >= 1, ">= 1"),
            ("base_resolution", s.base_resolution >= 2, ">= 2"),
            ("max_resolution", min(s.max_resolution) >= s.base_resolution,
             ">= base_resolution"),
            ("loss_weight", s.loss_weight >= 0, ">= 0"), ("padding", s.padding >= 0, ">= 0"))
  for name, ok, want in checks:
    if not ok:
      return f"{name}={getattr(s, name)}: must be {want}"
  return None


@dataclasses.dataclass(frozen=True)
class ProposalSampler(placement.Sampler):
  """Samples placed by proposal levels (nerfacto's ProposalNetworkSampler).

  Each ray starts with settings.num_samples[0] intervals spaced as the Sampler's (linear in t
  inside the inner box and in disparity beyond with data.contraction, else stratified over the
  scene box); level k's density function weighs its intervals (volume/quadrature.weights),
  and `resample` draws the next level's edges from those weights (with a key, as
  settings.resample says; stop_gradient: no loss moves a proposal through the placement); the
  last level's weights place the NeRF's `num_samples`. The levels'
  (t, weights) go to the renderer's outputs for `Interlevel`, which trains each level to bound
  the NeRF's weights; the NeRF's photometric loss gives the levels no gradient.

  settings: Settings. fields: one density-only Field per level (fields/density_field.py), whose
  parameters are variables['params']['proposal_<k>'] (`init`). The Sampler's fields are the
  NeRF's samples and the scene's box and spacing; occupancy is None.
  """
  settings: Settings = Settings()
  fields: Tuple = ()

  @property
  def names(self):
    """The parameter groups of the levels: ('proposal_0', 'proposal_1', ...)."""
    return tuple(f"proposal_{k}" for k in range(len(self.fields)))

  def init(self, key):
    keys = jax.random.split(key, len(self.fields))
    return {name: f.init(k) for name, f, k in zip(self.names, self.fields, keys)}

  def signature(self):
    s = self.settings
    signature = {"sampler": "proposal", "proposal_field": s.field,
                 "proposal_max_resolution": list(s.max_resolution), "proposal_levels": s.levels,
                 "proposal_features": s.features, "proposal_base_resolution": s.base_resolution,
                 "proposal_hidden": s.hidden}
    if s.field == "hash":
      signature["proposal_log2_size"] = s.log2_size
    return signature

  def loss_terms(self):
    return [Interlevel(self.settings.loss_weight)] if self.settings.loss_weight > 0 else []

  @property
  def marchable(self):
    return False  # a render must place its samples as training did

  def density_fns(self, params):
    """Each level's density function, points float32 [..., S, 3] -> sigma float32 [..., S]
    (per unit of world length), from the levels' parameters in `params` (variables['params'])."""
    return [lambda points, f=f, p=params[name]: f.query_density(p, points)
            for name, f in zip(self.names, self.fields)]

  def generate(self, rays, key=None, variables=None):
    """(Samples, extras) of `rays` [...] with the density functions of the levels' parameters
    in variables['params'] (`generate_from`)."""
    return self.generate_from(rays, self.density_fns(variables["params"]), key)

  def generate_from(self, rays, density_fns, key=None):
    """(Samples, extras): the NeRF's samples of `rays` [...] placed through one proposal level
    per density function (nerfstudio's generate_ray_samples(ray_bundle, density_fns)).

    density_fns: one per level, points float32 [..., S_k, 3] -> sigma float32 [..., S_k] (per
    unit of world length); level k takes settings.num_samples[k] samples. key: PRNG key for
    the initial jitter and the resampling (None: deterministic). extras: {'proposals': ({'t':
    float32 [..., S_k + 1], 'weights': float32 [..., S_k]}, ...)}, level 0 first. The levels'
    points are those of stop_gradient(rays): no proposal moves the cameras.
    """
    counts = tuple(self.settings.num_samples[:len(density_fns)]) + (self.num_samples,)
    keys = jax.random.split(key, len(counts)) if key is not None else [None] * len(counts)
    rays = jax.lax.stop_gradient(rays)
    t = jax.lax.stop_gradient(self._initial_edges(rays, counts[0], keys[0]))
    levels = []
    for density, count, level_key in zip(density_fns, counts[1:], keys[1:]):
      sigma = density(placement.points(rays, spacing.midpoints(t)))
      w = quadrature.weights(placement.per_unit_t(sigma, rays), t, exact_derivative=False)
      levels.append({"t": t, "weights": w})
      t = resample(t, w, count, level_key, self.settings.padding, self.settings.resample)
    return placement.on_edges(t), {"proposals": tuple(levels)}

  def _initial_edges(self, rays, count, key):
    """Edges float32 [..., count + 1] of the first level: `Sampler.stratified`'s spacing."""
    if self.contraction:
      return self._unbounded_edges(rays, count, key)
    t_near, t_far = self.bounds(rays)
    return spacing.stratified(t_near, t_far, count, rays.shape, key, lindisp=self.lindisp)

  def place(self, rays, key=None, grid=None):
    raise TypeError("ProposalSampler places samples with its density fields: call "
                    "generate(rays, key, variables)")


@dataclasses.dataclass(frozen=True)
class Interlevel:
  """The proposals' loss term (a callable on train/losses.LossInputs; samplers/ lies below
  train/): `weight` times the sum over levels of the rays' mean `interlevel_loss` of the level
  (outputs['sampler']['proposals']) against the NeRF's final pass (fine, else coarse), whose
  edges and weights are under stop_gradient: only the proposals learn from it.
  Stats (logged as 'interlevel/<stat>'): 'unweighted', the sum before the weight."""
  name: ClassVar[str] = "interlevel"  # the namespace of its stats (train/losses.total)
  weight: float = Settings.loss_weight

  def __call__(self, inputs):
    outs = inputs.outputs
    last = outs.get("fine", outs["coarse"])
    total = sum(jnp.mean(interlevel_loss(last["t"], last["weights"], level["t"],
                                         level["weights"]))
                for level in outs["sampler"]["proposals"])
    return self.weight * total, {"unweighted": total}


def build(settings, base):
  """The sampler's builder (samplers/registry.py): a ProposalSampler with config.proposal's
  `settings` (Settings) and the built-in Sampler `base`'s samples, box and spacing; ValueError
  naming the field for a setting that cannot work."""
  if base.occupancy is not None:
    raise ValueError("config.sampler='proposal' places the samples itself: set "
                     "config.occupancy.enabled=False")
  if base.scene_bound <= 0 and base.scene_bound != -1:
    raise ValueError("config.sampler='proposal' needs config.data.scene_bound > 0 or -1 "
                     "(auto): its density grids cover that box (and, with data.contraction, "
                     "the contracted space beyond it)")
  fields = tuple(density_field.density_field(_network(settings, r, base.grid_bound),
                                             base.contraction, base.scene_bound)
                 for r in settings.max_resolution)
  shared = {f.name: getattr(base, f.name) for f in dataclasses.fields(placement.Sampler)}
  return ProposalSampler(**shared, settings=settings, fields=fields)


def _network(settings, max_resolution, bound):
  """The density network of one level (fields/density_field.py) of `settings`, its finest
  lattice `max_resolution` points per side, over [-bound, bound]^3."""
  network = density_field.GridDensity if settings.field == "grid" else density_field.HashDensity
  return network(settings, max_resolution, bound)


# config.sampler = 'proposal' (samplers/registry.py); signature: the sampler's own `signature`.
SAMPLER = components.Component("proposal", Settings, build, signature=lambda settings: {})
