"""Where along each ray the field is queried: bounds, sample placement, points.

One place for what every renderer (training, image rendering, marching), the mesh export and
the profiler do between rays and the field: cut each ray to the scene box (`Sampler.bounds`),
place samples (`Sampler.place`: stratified, or in the occupied cells of an occupancy grid), and
turn distances into points (`points`, the only `o + d·t`) and into world length (`per_unit_t`,
`world_t`, the only |d| scaling).

rays: `rays.Rays` with batch shape `...`; t is z-depth along un-normalised directions (rays.py),
so a ray's t advances |d| world units per unit.
A placement (`Samples`) gives the edges t float32 [..., E + 1] that compositing sees and the
distances float32 [..., S] where the field is queried; `Samples.intervals` turns the field's
values at the S samples into values of the E intervals (E = S, or 2S with empty gaps between
occupied slots, see occupancy.py).
"""

import dataclasses
from typing import Optional, Tuple

import flax.struct
import jax
import jax.numpy as jnp

from nerf_jax.backend import components, draws
from nerf_jax.fields import contraction
from nerf_jax.samplers import occupancy, registry, spacing
from nerf_jax.samplers.occupancy import OccupancySettings
from nerf_jax.cameras.rays import ray_box_bounds
from nerf_jax.cameras.scene_settings import SceneSettings


def points(rays, distances):
  """float32 [..., S, 3]: o + d·t at distances float32 [..., S] along `rays` [...]."""
  return rays.origins[..., None, :] + rays.directions[..., None, :] * distances[..., None]


def per_unit_t(sigma, rays):
  """Density per unit of t: sigma float32 [..., S] (per unit of world length) times |d| of
  `rays` [...]. A ray's t advances |d| world units per unit, so its optical depth over [t_i,
  t_{i+1}] is σ·|d|·(t_{i+1} - t_i)."""
  return sigma * jnp.linalg.norm(rays.directions, axis=-1)[..., None]


def world_t(t, rays):
  """float32 [..., K]: distances t float32 [..., K] along `rays` [...] in world length (t·|d|)."""
  return t * jnp.linalg.norm(rays.directions, axis=-1)[..., None]


@flax.struct.dataclass
class Samples:
  """One placement of samples along rays [...].

  t: float32 [..., E + 1], sorted edges of the intervals composited.
  distances: float32 [..., S], where the field is queried (z-depth).
  valid: bool [..., S], samples that count (unused occupancy slots do not).
  gapped: static bool, interval 2k is sample k and interval 2k + 1 an empty gap after it
    (E = 2S); else interval k is sample k (E = S).
  """
  t: jnp.ndarray
  distances: jnp.ndarray
  valid: jnp.ndarray
  gapped: bool = flax.struct.field(pytree_node=False, default=False)

  def intervals(self, rgb, sigma):
    """(rgb float32 [..., E, 3], sigma float32 [..., E]) of the intervals from the samples'
    rgb float32 [..., S, 3] and density sigma float32 [..., S] (per unit of t)."""
    sigma = jnp.where(self.valid, sigma, 0.0)  # unused slots: zero-width and empty
    if not self.gapped:
      return rgb, sigma
    return occupancy.with_gaps(rgb, axis=-2), occupancy.with_gaps(sigma)


def on_edges(t):
  """Samples at the midpoints of the intervals of t float32 [..., S + 1]."""
  distances = spacing.midpoints(t)
  return Samples(t, distances, jnp.ones(distances.shape, bool))


@dataclasses.dataclass(frozen=True)
class Sampler:
  """How a ray's first pass is sampled.

  num_samples: samples per ray. scene_bound: half-size of the box [-b, b]^3 holding the scene;
  samples only inside it (0 = the whole of [near, far]). lindisp: space stratified samples
  linearly in 1/t. occupancy: where set, samples go only to occupied cells of an occupancy grid
  over the scene box (occupancy.py), passed to `place` as `grid`.
  contraction: '' (bounded), or 'l2' / 'linf' for an unbounded scene (contraction.py): the box
  of half-size scene_bound is the inner region, sampled linearly in t; beyond it samples are
  linear in disparity out to far = infinity (spacing.stratified_unbounded), `inner_fraction`
  of them inside.
  occupancy_box: with occupancy in NDC (no scene box: scene_bound 0), the box (min x, y, z,
  max x, y, z) the grid covers, mapped onto its cube (occupancy.to_cube); None elsewhere.
  """
  num_samples: int
  scene_bound: float = SceneSettings.scene_bound  # defaults: the settings' (declared once)
  lindisp: bool = SceneSettings.lindisp
  occupancy: Optional[OccupancySettings] = None
  contraction: str = SceneSettings.contraction
  inner_fraction: float = SceneSettings.inner_fraction
  occupancy_box: Optional[Tuple[float, ...]] = None

  def bounds(self, rays):
    """(t_near, t_far) float32 [...]: the rays' [near, far], cut to the scene box if any (an
    unbounded scene's rays run from near to infinity)."""
    if self.contraction:
      return rays.near, jnp.full_like(rays.far, jnp.inf)
    if self.scene_bound > 0:  # sample only the part of each ray inside the scene box
      return ray_box_bounds(rays.origins, rays.directions, self.scene_bound, rays.near,
                            rays.far)
    return rays.near, rays.far

  def stratified(self, rays, key=None):
    """Edges t float32 [..., S + 1] of stratified samples over `bounds` (key None: even)."""
    if self.contraction:
      return self._unbounded_edges(rays, self.num_samples, key)
    t_near, t_far = self.bounds(rays)
    return spacing.stratified(t_near, t_far, self.num_samples, rays.shape, key,
                               lindisp=self.lindisp)

  def _unbounded_edges(self, rays, count, key=None):
    """Edges float32 [..., count + 1]: linear in t inside the inner box, in disparity beyond."""
    t_near, t_far = self.bounds(rays)
    t_inner = contraction.inner_exit(rays.origins, rays.directions, self.scene_bound,
                                     self.contraction)
    return spacing.stratified_unbounded(t_near, t_inner, t_far, count, rays.shape, key,
                                         self.inner_fraction)

  def unit_distance(self, t, rays):
    """s float32 [..., K]: distances t float32 [..., K] along `rays` [...] as a normalised ray
    distance, mip-NeRF 360's s, in which its distortion loss is measured so that the loss does
    not depend on the scene's units. Bounded: the share of the rays' [near, far] before t
    (NDC's t already is one); unbounded: `spacing.unbounded_unit`, the share of the samples
    before t (linear inside the inner box, in disparity beyond, as the samples are spaced)."""
    if self.contraction:
      t_inner = contraction.inner_exit(rays.origins, rays.directions, self.scene_bound,
                                       self.contraction)
      return spacing.unbounded_unit(t, rays.near, t_inner, jnp.inf, self.inner_fraction)
    near, far = rays.near[..., None], rays.far[..., None]
    return (t - near) / jnp.maximum(far - near, 1e-6)  # far > near for any data; never 1/0

  @property
  def grid_bound(self):
    """Half-size of the cube an occupancy grid covers: the scene box, in an unbounded scene
    the contracted space (twice the inner box), with an occupancy_box the cube [-1, 1]^3 that
    box is mapped onto."""
    if self.occupancy_box is not None:
      return 1.0
    return contraction.OUTER * self.scene_bound if self.contraction else self.scene_bound

  def grid_cells(self, world):
    """float32 [..., 3]: points world float32 [..., 3] the field sees as points of the grid's
    cube (contracted, or of the occupancy_box mapped onto it): the inverse of `grid_points`."""
    if self.occupancy_box is not None:
      return occupancy.to_cube(world, self.occupancy_box)
    if self.contraction:
      return contraction.contract(world, self.scene_bound, self.contraction)
    return world

  def grid_points(self, cells):
    """float32 [..., 3]: points cells float32 [..., 3] of the grid's cube as the points of
    space the field sees there (uncontracted, or of the occupancy_box)."""
    if self.occupancy_box is not None:
      return occupancy.from_cube(cells, self.occupancy_box)
    if self.contraction:
      return contraction.uncontract(cells, self.scene_bound, self.contraction)
    return cells

  # The interface every sampler shares (samplers/registry.py): the renderer calls `generate`,
  # `RayRenderer.init` adds `init`'s parameter groups, the checkpoint signature records
  # `signature`, the loss lists `loss_terms`. A learned sampler (proposal.py) overrides them.

  def init(self, key):
    """The parameter groups this sampler trains, {name: params} from PRNG key `key`, stored in
    variables['params'] beside the field's networks: none."""
    del key
    return {}

  def signature(self):
    """Checkpoint signature entries ({key: JSON value}) fixing the shapes of `init`'s
    parameters: none (so checkpoints of the built-in sampler are unchanged)."""
    return {}

  def loss_terms(self):
    """Loss terms this sampler brings (callables on train/losses.LossInputs): none."""
    return []

  @property
  def marchable(self):
    """Whether a render may replace this placement by marching stratified samples through the
    scene box (image_renderer.marches): plain stratified samples in a box only."""
    return self.scene_bound > 0 and self.occupancy is None and not self.contraction

  def generate(self, rays, key=None, variables=None):
    """(Samples, extras) of `rays` [...]: `place` with the occupancy grid of `variables`
    (renderer.py's; None = no grid), and no extras (a dict the renderer puts in its outputs as
    outputs['sampler'] when it is not empty, for a sampler's loss terms)."""
    grid = None if variables is None else variables.get("occupancy")
    return self.place(rays, key, grid), {}

  def place(self, rays, key=None, grid=None):
    """Samples of `rays` [...]: stratified, or with `occupancy` in the occupied cells of `grid`
    (float32 [R, R, R], occupancy.py). key: PRNG key for the jitter (None: deterministic)."""
    if self.occupancy is None:
      return on_edges(self.stratified(rays, key))
    oc = self.occupancy
    mask = occupancy.occupied_mask(jax.lax.stop_gradient(grid), oc.threshold)
    if self.contraction or self.occupancy_box is not None:
      # Candidates spaced as the samples would be (unbounded: in disparity beyond the inner
      # box; NDC: evenly in its t), each looked up at its point in the grid's cube.
      edges = (self._unbounded_edges(rays, oc.candidates) if self.contraction else
               spacing.stratified(*self.bounds(rays), oc.candidates, rays.shape,
                                   lindisp=self.lindisp))
      t_far = edges[..., -1]
      cells = self.grid_cells(points(rays, spacing.midpoints(edges)))
      occupied = (occupancy.lookup(mask, cells, self.grid_bound)
                  & (t_far > edges[..., 0])[..., None])  # an empty segment has no candidates
      starts, ends, valid = occupancy.occupied_slots(edges, occupied, self.num_samples, t_far)
    else:
      t_near, t_far = self.bounds(rays)
      starts, ends, valid = occupancy.sample_occupied(
          mask, rays.origins, rays.directions, t_near, t_far, self.scene_bound, oc.candidates,
          self.num_samples)
    u = 0.5 if key is None else draws.uniform(key, starts.shape, jnp.float32)
    return Samples(occupancy.interleave_gaps(starts, ends, t_far),
                   starts + (ends - starts) * u, valid, gapped=True)


def build(settings, base):
  """The built-in placement's builder (samplers/registry.py): `base` itself, whose settings are
  the config's num_samples, data.* and occupancy.* (run/builders.make_sampler); `section` is
  None."""
  del settings
  return base


SAMPLER = components.Component(registry.BUILTIN, None, build)  # config.sampler '' or 'placement'
