"""Rendering rays: sample -> query the field -> composite, with an optional fine pass.

rays: `rays.Rays` (origins, directions, viewdirs, near, far) with batch shape `...`.
variables: {'params': {'coarse': ..., ['fine': ...], [the sampler's groups]}, ['occupancy':
float32 [R, R, R]]}, the trained parameters of each network (and of a learned sampler, e.g.
'proposal_0': `Sampler.init`) and, beside them, the state that is not trained (the occupancy
grid, kept by training: occupancy.py), as Flax keeps `batch_stats` beside `params`.
A pass's output (a dict): rgb float32 [..., 3], depth float32 [...], acc float32 [...],
weights float32 [..., E], t float32 [..., E + 1]. The sampler places the first pass's samples
(`sampler.generate(rays, key, variables)`, handed the variables to build its density
functions from); what else it returns (a learned sampler's levels, arrays with the rays'
leading axes) is outputs['sampler'], for its loss terms.
The field's density is per unit of world length; t is z-depth along un-normalised directions,
so every pass composites `placement.per_unit_t(sigma, rays)` = σ·|d| (as the original NeRF,
jaxnerf and multinerf scale their intervals by |d|), and depth stays z-depth.
Rendering whole images in fixed-size chunks is image_renderer.py.
"""

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp

from nerf_jax.render import compositing
from nerf_jax.samplers import occupancy, placement, spacing, visual_hull
from nerf_jax.fields.field import Field
from nerf_jax.samplers.placement import Sampler


# fold_in(key, SAMPLER_KEY) is the key of a sampler's parameters in `RayRenderer.init`.
SAMPLER_KEY = 0x5A4D
# fold_in(key, TRANSIENT_KEY) is the key of the transient head's parameters.
TRANSIENT_KEY = 0x7A11
# fold_in(key, MULTISAMPLE_KEY) of a pass's key turns its frustums' multisamples (Zip-NeRF's
# training jitter; a fold_in, not a split, so the pass's density noise keeps its key).
MULTISAMPLE_KEY = 0x6E7


@dataclasses.dataclass(frozen=True)
class FineSettings:
  """config's top-level field of the fine pass."""
  num_fine_samples: int = 0  # extra samples drawn from the coarse weights (0 = no hierarchy)


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.model's fields of how the renderer uses the field."""
  colour_fraction: float = 0.0  # density grid: colour only for this share of samples (top weights)
  shared_fine: bool = False  # one network for coarse and fine passes instead of two


@dataclasses.dataclass(frozen=True)
class RayRenderer:
  """A field, how its first pass is sampled, and the optional fine pass.

  num_fine_samples: samples drawn from the first pass's weights for a second pass (0 = none).
  shared_fine: the fine pass queries the coarse network instead of a network of its own.
  colour_fraction: with a field that gives density alone (Field.splits_density), a pass
    computes the density of every sample, then colour only for this share of the batch's
    samples, those of largest weight (`_shade_where_it_matters`); 0 = colour everywhere.
  sample_budget: with occupancy-placed samples, the field is queried at most at this many of
    the batch's valid samples, compacted (`budgeted_slots`; training sets it, nerfacc's fixed
    sample budget): empty slots cost nothing, so a batch can hold more rays. A ray whose
    samples did not all fit is marked incomplete (out['complete']) and left out of the loss;
    the colour budget is then a share of the budget. out['valid_samples'] counts each ray's
    valid samples, fitted or not (what the rays asked of the budget: train/losses/colour.py
    logs their sum, so a run shows whether its rays fill it). 0 = every slot of every ray.
  transient: a fields/transient_field.TransientField (NeRF-W's transient head) or None. With one,
    the final pass of rays that carry their training image (rays.image: training batches)
    composites it with the static field (compositing.composite_with_transient: its outputs
    add transient_weights, beta and transient_density, the head's sigma float32 [..., S] per
    unit of world length); rays without an image (held-out views, renders) see the static
    field alone. Its parameters are variables['params']['transient'].
  """
  field: Field
  sampler: Sampler
  num_fine_samples: int = FineSettings.num_fine_samples  # defaults: the settings' (declared once)
  shared_fine: bool = Settings.shared_fine
  colour_fraction: float = Settings.colour_fraction
  sample_budget: int = 0  # none
  transient: Any = None

  @property
  def uses_images(self):
    """Whether rays take their training image: for appearance codes or the transient head."""
    return self.field.uses_images or self.transient is not None

  @property
  def networks(self):
    """Parameter groups: a fine network exists only with a fine pass and unshared nets."""
    if self.num_fine_samples > 0 and not self.shared_fine:
      return ("coarse", "fine")
    return ("coarse",)

  def init(self, key):
    """variables (module docstring): each network's parameters from `key`, and the sampler's
    (`Sampler.init`, from a key of its own); the occupancy grid at zeros, which counts as
    occupied everywhere (occupancy.py)."""
    keys = jax.random.split(key, 2)
    variables = {"params": {name: self.field.init(k) for name, k in zip(self.networks, keys)}}
    # fold_in, not a third split: split(key, 3) would change the networks' keys.
    own = self.sampler.init(jax.random.fold_in(key, SAMPLER_KEY))
    clash = set(own) & (set(variables["params"]) | {"poses"})
    if clash:
      raise ValueError(f"the sampler's parameter groups {sorted(clash)} clash with the "
                       "field's networks or the poses: name them apart")
    variables["params"].update(own)
    if self.transient is not None:  # fold_in, not a split: the networks' keys stay as they were
      variables["params"]["transient"] = self.transient.init(
          jax.random.fold_in(key, TRANSIENT_KEY))
    if self.sampler.occupancy is not None:
      variables["occupancy"] = self.sampler.occupancy.empty_grid()
    return variables

  def final_params(self, variables):
    """The parameters of the network that renders the final pass."""
    return variables["params"][self.networks[-1]]

  def _shade(self, params, rays, samples, background, key, remat_chunk=0, bands=None,
             transient_params=None, hull=None):
    """One pass over `samples` (placement.Samples) with one network's `params`, and the
    transient head's `transient_params` (None: the static field alone); with a visual `hull`
    (`hull_of`), no density outside it."""
    budget = self.sample_budget if samples.gapped and rays.near.ndim == 1 else 0
    distances = samples.distances
    if samples.gapped and not budget:  # not recomputed in every reader (occupancy.computed_once)
      distances = occupancy.computed_once(distances)
    points = placement.points(rays, distances)
    # The gate of the samples' world points, before the frustums' inputs replace them.
    gate = None if hull is None else visual_hull.gate(hull[0], points, hull[1])
    gated = lambda sigma: sigma if gate is None else sigma * gate
    per_sample = None
    if self.field.cones:  # the frustums of the samples' intervals, queried at their means
      cone_key = None if key is None else jax.random.fold_in(key, MULTISAMPLE_KEY)
      points, per_sample = self.field.cone_inputs(rays, *sample_intervals(samples), cone_key)
    if transient_params is not None and (budget or self.colour_fraction > 0):
      raise ValueError("config.model.transient does not work with config.train.sample_budget "
                       "or config.model.colour_fraction yet: set them to 0")
    if budget:
      slots, complete = budgeted_slots(samples.valid, budget)
    if self.colour_fraction > 0 and self.field.splits_density:
      if budget:
        sigma = _at_slots(lambda p, c: self.field.query_density(
            params, p[:, None], key, with_sample_axis(c))[:, 0], slots, points, per_sample)
      else:
        sigma = self.field.query_density(params, points, key, per_sample)
      out = self._shade_where_it_matters(params, rays, samples, points, gated(sigma), background,
                                         complete if budget else None, per_sample)
    else:
      if budget:
        rgb, sigma = self._query_at_slots(params, rays, points, slots, key, bands, per_sample)
      else:
        rgb, sigma = self.field.query_in_chunks(params, points, rays.viewdirs, key,
                                                remat_chunk, rays.image, bands, per_sample)
      sigma = gated(sigma)
      if transient_params is not None:
        return self._shade_with_transient(transient_params, rays, samples, points, rgb, sigma,
                                          background)
      rgb, sigma = samples.intervals(rgb, placement.per_unit_t(sigma, rays))
      out = compositing.composite(rgb, sigma, samples.t, background)
      out["t"] = samples.t
    if budget:
      out["complete"] = complete
      out["valid_samples"] = jnp.sum(samples.valid, axis=-1, dtype=jnp.int32)
    return out

  def _shade_with_transient(self, params, rays, samples, points, rgb, sigma, background):
    """The pass's output of the static field's rgb float32 [R, S, 3] and sigma float32 [R, S]
    at points float32 [R, S, 3] composited with the transient head's (params: its parameters)
    at the same points, for the rays' images (NeRF-W, eq. 10)."""
    rgb_t, sigma_t, beta = self.transient.query(params, self.field.network_points(points),
                                                rays.image)
    rgb, sigma = samples.intervals(rgb, placement.per_unit_t(sigma, rays))
    # Colour and uncertainty travel together through the gaps' interleaving.
    both, sigma_t_e = samples.intervals(jnp.concatenate([rgb_t, beta[..., None]], axis=-1),
                                        placement.per_unit_t(sigma_t, rays))
    out = compositing.composite_with_transient(rgb, sigma, both[..., :3], sigma_t_e,
                                               both[..., 3], samples.t, background,
                                               beta_min=self.transient.beta_min)
    out["t"] = samples.t
    out["transient_density"] = jnp.where(samples.valid, sigma_t, 0.0)
    return out

  def _query_at_slots(self, params, rays, points, slots, key, bands, per_sample=None):
    """`Field.query` at the compacted `slots` (int32 [B], from `budgeted_slots`) of points
    float32 [R, S, 3] only (and of per_sample, `Field.cone_inputs`' dict of arrays [R, S, ...],
    or None). Returns rgb float32 [R, S, 3] and sigma float32 [R, S], zero at every other
    slot."""
    num_samples = points.shape[1]
    ray = jnp.minimum(slots, points.shape[0] * num_samples - 1) // num_samples
    image = rays.image
    images = None if image is None or not self.field.uses_images else image[ray][:, None]

    def query(p, cone):
      cone = {} if cone is None else {"per_sample": with_sample_axis(cone)}
      rgb, sigma = self.field.query(params, p[:, None], rays.viewdirs[ray], key, images, bands,
                                    **cone)
      return jnp.concatenate([rgb[:, 0], sigma], axis=-1)
    both = _at_slots(query, slots, points, per_sample)
    return both[..., :3], both[..., 3]

  def _shade_where_it_matters(self, params, rays, samples, points, sigma, background,
                              complete=None, per_sample=None):
    """`_shade` with colour only where it counts (TensoRF's and DVGO's saving): density for all
    samples first; then the K = ceil(colour_fraction · samples) samples of largest compositing
    weight (over the whole batch, a fixed K so the shapes stay static) get their colour, and
    every other sample is composited black. A sample left out has at most the K-th largest
    weight, so the colour it would add is bounded by that weight
    (tests/fields/networks/test_grid.py).
    sigma: float32 [R, S], the field's density at `points`. complete: bool [R] or None,
    the rays whose density is whole (a sample budget: K is then a share of the budget, and
    incomplete rays get no colour). per_sample: None, or `Field.cone_inputs`' dict of arrays
    [R, S, ...] (a field of cones: the chosen samples' frustums are read).
    """
    sigma = placement.per_unit_t(sigma, rays)
    black = jnp.zeros(points.shape, jnp.float32)
    black_e, sigma_e = samples.intervals(black, sigma)
    weights = compositing.composite(black_e, jax.lax.stop_gradient(sigma_e), samples.t)["weights"]
    if samples.gapped:  # interval 2k is sample k
      weights = weights[..., ::2]
    samples_shaded = weights.size
    if complete is not None:
      weights = jnp.where(complete[:, None], weights, -1.0)
      samples_shaded = self.sample_budget
    flat_weights = weights.reshape(-1)
    count = max(1, min(flat_weights.size, math.ceil(self.colour_fraction * samples_shaded)))
    _, chosen = jax.lax.top_k(flat_weights, count)  # [K] flat sample indices
    per_ray = points.shape[-2]
    viewdirs = rays.viewdirs.reshape(-1, 3)[chosen // per_ray]
    cone = None if per_sample is None else _at_flat(per_sample, chosen, points.shape[:2])
    image = (None if rays.image is None or not self.field.uses_images else
             rays.image.reshape(-1)[chosen // per_ray])  # each chosen sample's ray's image
    colour = self.field.query_colour(params, points.reshape(-1, 3)[chosen], viewdirs, cone,
                                     image)
    rgb = black.reshape(-1, 3).at[chosen].set(colour).reshape(points.shape)
    rgb, sigma = samples.intervals(rgb, sigma)
    out = compositing.composite(rgb, sigma, samples.t, background)
    out["t"] = samples.t
    return out

  def render(self, variables, rays, key=None, background=None, remat_chunk=0, bands=None):
    """Render a batch of rays with the coarse and (optionally) fine passes.

    variables: see the module docstring (with 'hull', a visual hull: every pass has no density
    outside it, `hull_of`). rays: Rays [...] (rays.image: each ray's training
    image, for its appearance code; None = the mean code). key: PRNG key for stratified jitter,
    resampling, density noise and the multisamples' turns (Field.cone_inputs); None renders
    deterministically. background: None or float32
    broadcastable to [..., 3]. remat_chunk: rays per recomputed field chunk of a pass
    (Field.query_in_chunks; training sets it, 0 = one call). bands: float32 [] or None,
    positional-encoding bands open (BARF; None = all). See field.py.
    Returns {'coarse': pass_output, ['fine': pass_output], ['sampler': the sampler's extras]}.
    """
    keys = jax.random.split(key, 4) if key is not None else [None] * 4
    params = variables["params"]
    samples, extras = self.sampler.generate(rays, keys[0], variables)
    if samples.gapped:  # occupancy-placed slots: few per ray, no chunks needed
      remat_chunk = 0
    # The transient head joins the final pass of rays that carry their training image.
    transient = (params["transient"] if self.transient is not None and rays.image is not None
                 else None)
    has_fine = self.num_fine_samples > 0
    hull = hull_of(variables, self.sampler.scene_bound)
    outputs = {"coarse": self._shade(params["coarse"], rays, samples, background, keys[1],
                                     remat_chunk, bands, None if has_fine else transient, hull)}
    if self.num_fine_samples > 0:
      t = samples.t
      extra = spacing.sample_pdf(t, outputs["coarse"]["weights"], self.num_fine_samples,
                                  keys[2])
      fine = placement.on_edges(spacing.merge_edges(t, extra))
      outputs["fine"] = self._shade(self.final_params(variables), rays, fine, background,
                                    keys[3], remat_chunk, bands, transient, hull)
    if self.sampler.scene_bound > 0:
      for out in outputs.values():
        out["depth"] = empty_depth_is_far(out, rays.far)
    if extras:
      outputs["sampler"] = extras
    return outputs

  def occupancy_grid(self, variables, key=None):
    """The occupancy grid of the coarse network's density: float32 [R, R, R] (occupancy.py),
    probed at `probes` per cell side, jittered from `key` (None: not jittered)."""
    oc, rs = self.sampler.occupancy, self.sampler
    density = self.field.density(variables["params"]["coarse"])
    if rs.contraction or rs.occupancy_box is not None:  # cells of contracted space, or of
      # the cube an NDC box is mapped onto: probe the points the field sees there
      density = lambda cells, fn=density: fn(rs.grid_points(cells))
    return occupancy.density_grid(density, oc.resolution, rs.grid_bound, oc.probes, key)


def occupancy_hull(sampler, hull, hull_bound):
  """float32 [R, R, R]: the visual hull `hull` float32 [H, H, H] over the box
  [-hull_bound, hull_bound]^3 at the centres of the R^3 cells of `sampler`'s occupancy grid
  (placement.Sampler with occupancy settings; cells of contracted space mapped back to the
  points the field sees there): 1 where a cell's centre is kept, 0 where carved or outside.
  The hull itself where it was carved on the occupancy grid (its box, R cells a side, no
  contraction); a subject's hull has its own box and cells (run/from_data.subject_hull)."""
  cells = occupancy.cell_centres(sampler.occupancy.resolution, sampler.grid_bound)
  return visual_hull.gate(hull, sampler.grid_points(cells), hull_bound)


def hull_of(variables, scene_bound):
  """(hull float32 [R, R, R], bound) of `variables`' visual hull over the box [-bound, bound]^3:
  variables['hull'], over variables['hull_bound'] where the run keeps one (a subject's hull)
  else over the scene box; None without a hull."""
  if "hull" not in variables:
    return None
  return variables["hull"], variables.get("hull_bound", scene_bound)


def sample_intervals(samples):
  """(t0, t1), each float32 [..., S]: the interval [t0, t1) of each sample of `samples`
  (placement.Samples): intervals k, or 2k with gaps (E = 2S, occupancy.py)."""
  t = samples.t
  if samples.gapped:
    return t[..., 0:-1:2], t[..., 1::2]
  return t[..., :-1], t[..., 1:]


def budgeted_slots(valid, budget):
  """The first `budget` valid samples of a batch, in ray order (a fixed sample budget).

  valid: bool [R, S]. budget: int B.
  Returns (slots int32 [B], complete bool [R]): the flat indices (r·S + s) of the first B valid
  samples, padded with R·S where fewer are valid; and the rays all of whose valid samples are
  among them (a prefix of the rays: the ones after the budget ran out are incomplete).
  """
  flat = valid.reshape(-1)
  slots = jnp.nonzero(flat, size=budget, fill_value=flat.size)[0].astype(jnp.int32)
  # Counts are at most R·S < 2^31: exact in int32.
  valid_through = jnp.cumsum(jnp.sum(valid, axis=-1, dtype=jnp.int32))
  return slots, valid_through <= budget


def _at_slots(fn, slots, points, per_sample=None):
  """fn's values at the points of `slots` only, scattered back to every slot (zero elsewhere).

  fn: (points float32 [B, 3], per-sample inputs at them or None) -> float32 [B, ...]. slots:
  int32 [B] flat indices into points float32 [R, S, 3], R·S where unused (those are dropped).
  per_sample: None, or a dict of arrays [R, S, ...] (`Field.cone_inputs`). Returns float32
  [R, S, ...].
  """
  num_rays, num_samples = points.shape[:2]
  total = num_rays * num_samples
  index = jnp.minimum(slots, total - 1)
  cone = None if per_sample is None else _at_flat(per_sample, index, points.shape[:2])
  values = fn(points.reshape(total, 3)[index], cone)
  out = jnp.zeros((total,) + values.shape[1:], values.dtype)
  return out.at[slots].set(values, mode="drop").reshape(num_rays, num_samples, *values.shape[1:])


def _at_flat(per_sample, index, leading):
  """The entries of a dict of arrays [R, S, ...] (`leading` = (R, S)) at flat sample indices
  int32 [B] (r·S + s): arrays [B, ...]."""
  total = leading[0] * leading[1]
  return jax.tree_util.tree_map(lambda a: a.reshape(total, *a.shape[2:])[index], per_sample)


def with_sample_axis(per_sample):
  """A dict of arrays [B, ...] (one sample each) as [B, 1, ...], the sample axis `Field.query`
  reads; None stays None."""
  return None if per_sample is None else jax.tree_util.tree_map(lambda a: a[:, None],
                                                                 per_sample)


def empty_depth_is_far(out, far):
  """float32 [...]: out['depth'] with `far` (float32 [...]) for empty rays (acc <= EMPTY_ACC).

  In a scene box composite gives an empty ray the box exit t_S; this makes it `far` on every
  code path, as without a box.
  """
  return jnp.where(out["acc"] > compositing.EMPTY_ACC, out["depth"], far)


def final(outputs):
  """The best pass of `render` outputs: fine if present, else coarse."""
  return outputs.get("fine", outputs["coarse"])
