"""Empty-space skipping: an occupancy grid over the scene box, and sampling only where it is full.

The grid (`OccupancySettings`, from config.occupancy) is float32 [R, R, R]: the largest density σ
found in each cell of the box [-bound, bound]^3 by probes on a sub-cell lattice, max-pooled over the
neighbouring cells so structure thinner than a cell is not lost (`density_grid` says how thin).
Every `update_every` steps training probes the density field again at jittered positions (a key
folded from the step) and keeps max(decay·old, new) (Instant-NGP's update, `accumulate`): probes add
up across refreshes and density that has gone is forgotten. The grid is not trained: it lives beside
the parameters, as the train state's buffers['occupancy'] (checkpointed and restored with them, so a
resumed run uses exactly the grid it would have).

Sampling with static shapes: each ray's segment inside the box is cut into M candidate intervals
of width Δ = segment / M; the occupied candidates, in order, are dealt into K = num_samples
slots. With n <= K occupied candidates, slot k is candidate k exactly (fine spacing where there is
something, nothing spent elsewhere; unused slots are zero-width at the segment's end). With n > K
(early in training every cell is occupied), slot k groups candidates of rank [k·n/K, (k+1)·n/K)
and spans them from the first's start to the last's end, so an all-occupied ray gets plain
stratified sampling. Between slots lie gaps of empty space, composited as intervals of zero
density, so `compositing.composite` and its numerics are used unchanged.

A cell is occupied when its σ >= min(threshold, mean σ of the grid) (Instant-NGP's rule): an
untrained, uniformly faint field counts as occupied everywhere instead of empty everywhere.
"""

import dataclasses

import jax
import jax.numpy as jnp

from nerf_jax.backend import draws


@dataclasses.dataclass(frozen=True)
class OccupancySettings:
  """An occupancy grid over the scene box and how training keeps it (module docstring)."""
  resolution: int = 32  # occupancy cells per side of the box
  candidates: int = 256  # candidate intervals per ray; the occupied ones share num_samples samples
  update_every: int = 16  # train steps between probing the density field again
  probes: int = 2  # probes per cell side at each refresh, at jittered positions
  decay: float = 0.95  # each refresh keeps max(decay·old, new): probes add up, gone density fades
  threshold: float = 1.0  # density (per scene unit) from which a cell counts as occupied
  enabled: bool = False  # sample only in occupied cells of a grid over data.scene_bound's box

  def empty_grid(self):
    """float32 [R, R, R] zeros: the grid before the first refresh (occupied everywhere)."""
    return jnp.zeros((self.resolution,) * 3, jnp.float32)


def cell_centres(resolution, bound):
  """float32 [R, R, R, 3]: the centres of the R^3 cells of the box [-bound, bound]^3."""
  c = (jnp.arange(resolution, dtype=jnp.float32) + 0.5) / resolution * 2.0 * bound - bound
  return jnp.stack(jnp.meshgrid(c, c, c, indexing="ij"), axis=-1)


def probe_offsets(probes):
  """float32 [P^3, 3]: a cell's probes in cells from its centre, the lattice (j + 0.5)/P - 0.5,
  j = 0..P-1 per axis (spacing 1/P; P = 2 gives the 8 points at ±0.25)."""
  j = (jnp.arange(probes, dtype=jnp.float32) + 0.5) / probes - 0.5
  return jnp.stack(jnp.meshgrid(j, j, j, indexing="ij"), axis=-1).reshape(-1, 3)


def density_grid(density_fn, resolution, bound, probes=OccupancySettings.probes, key=None):
  """The occupancy grid of a density field: float32 [R, R, R].

  density_fn: points float32 [P, 3] -> σ float32 [P]. probes: int P, probes per cell side: σ is
  probed on a lattice of spacing h = cell / P (`probe_offsets`), one x-slab of cells at a time
  (bounded memory); key: None for that lattice, else each cell's lattice is shifted by its own
  uniform offset in [-h/2, h/2)^3 (random positions, accumulated across refreshes by
  `accumulate`). The largest σ of each cell is then max-pooled over its 3×3×3 neighbourhood.

  What the lattice (key=None, P >= 2) finds, see docs/numerics.md: a point x of a structure that
  lies in a ball of radius (√3/2)·h inside it (density >= σ) has a probe p inside that ball (the
  lattice's covering radius is (√3/2)·h), |p - x| <= √3·h < 1 cell, so p is in x's cell or a
  neighbour and the pooling gives x's cell at least σ: a slab or rod at least √3·h thick is never
  lost. Thinner ones can fall between the probes; jittered refreshes find them over time.
  """
  cell = 2.0 * bound / resolution
  centres = cell_centres(resolution, bound)  # [R, R, R, 3]
  if key is None:
    shifts = jnp.zeros_like(centres)
  else:
    shifts = (draws.uniform(key, centres.shape, jnp.float32) - 0.5) / probes
  offsets = probe_offsets(probes)

  def slab(args):  # centres, shifts [R, R, 3] -> [R, R]
    points, shift = args
    probed = points[:, :, None, :] + cell * (offsets + shift[:, :, None, :])
    return density_fn(probed.reshape(-1, 3)).reshape(resolution, resolution, -1).max(-1)

  sigma = jax.lax.map(slab, (centres, shifts))
  return jax.lax.reduce_window(sigma, -jnp.inf, jax.lax.max, (3, 3, 3), (1, 1, 1), "SAME")


def to_cube(points, box):
  """float32 [..., 3]: points float32 [..., 3] of `box` (min x, y, z, max x, y, z) mapped
  affinely onto the cube [-1, 1]^3, whose cells a grid over the box then divides (an NDC run's
  grid covers the box of its training rays, not a cube around the origin)."""
  low, high = jnp.asarray(box[:3], jnp.float32), jnp.asarray(box[3:], jnp.float32)
  return (points - low) / (high - low) * 2.0 - 1.0


def from_cube(cells, box):
  """float32 [..., 3]: the inverse of `to_cube`, points of [-1, 1]^3 as points of `box`."""
  low, high = jnp.asarray(box[:3], jnp.float32), jnp.asarray(box[3:], jnp.float32)
  return low + (cells + 1.0) * 0.5 * (high - low)


def accumulate(old, new, decay):
  """Instant-NGP's update of a grid float32 [R, R, R]: max(decay·old, new).

  Jittered probes of successive refreshes add up (a structure missed by one refresh's probes is
  kept from an earlier one), while decay < 1 forgets density that has gone: a cell once high
  falls below any threshold after a few refreshes, and a cell once empty is back as soon as a
  refresh finds density there."""
  return jnp.maximum(decay * old, new)


def occupied_mask(grid, threshold):
  """bool [R, R, R]: cells whose density reaches min(threshold, mean density)."""
  # The mean of a uniform grid can round a few ulps above its value: compare with some slack.
  return grid >= jnp.minimum(threshold, jnp.mean(grid)) * (1.0 - 1e-5)


def lookup(mask, points, bound):
  """bool [...]: the cell of `mask` [R, R, R] holding each point float32 [..., 3] (clamped)."""
  res = mask.shape[0]
  idx = jnp.clip(jnp.floor((points + bound) / (2.0 * bound) * res), 0, res - 1).astype(jnp.int32)
  return mask[idx[..., 0], idx[..., 1], idx[..., 2]]


def _candidates_of_ranks(occupied, ranks):
  """int32 [..., J]: the candidate holding each rank (0-based, in order) among the True entries
  of bool [..., M]; M - 1 for a rank past the last. A binary search of the running count of
  occupied candidates, rank r held by the first candidate whose count exceeds r: log2(M) small
  gathers per rank, where listing every occupied candidate (nonzero) scatters all M."""
  m = occupied.shape[-1]
  count = jnp.cumsum(occupied, axis=-1, dtype=jnp.int32).reshape(-1, m)  # exact: <= M
  flat_ranks = ranks.reshape(-1, ranks.shape[-1])
  idx = jax.vmap(lambda c, r: jnp.searchsorted(c, r, side="right"))(count, flat_ranks)
  return jnp.minimum(idx, m - 1).reshape(ranks.shape).astype(jnp.int32)


def sample_occupied(mask, origins, directions, t_min, t_max, bound, num_candidates, num_samples):
  """Intervals of each ray inside occupied cells (see the module docstring).

  mask: bool [R, R, R] from `occupied_mask`. origins, directions: float32 [..., 3].
  t_min, t_max: float32 [...], the segment inside the box (`rays.ray_box_bounds`).
  num_candidates: int M. num_samples: int K.
  Returns (starts, ends, valid): float32 [..., K], float32 [..., K], bool [..., K]; intervals
  are sorted and disjoint, inside [t_min, t_max]; invalid slots are [t_max, t_max].
  """
  s = jnp.linspace(0.0, 1.0, num_candidates + 1, dtype=jnp.float32)
  edges = t_min[..., None] + (t_max - t_min)[..., None] * s  # [..., M + 1], monotone in s
  mids = 0.5 * (edges[..., 1:] + edges[..., :-1])
  points = origins[..., None, :] + directions[..., None, :] * mids[..., None]
  occupied = lookup(mask, points, bound) & (t_max > t_min)[..., None]
  first, last, valid = slot_candidates(occupied, num_samples)
  # Equal candidates: a slot's edges are arithmetic on its candidates, not a gather.
  width = ((t_max - t_min) / num_candidates)[..., None]
  far = t_max[..., None]
  edge = lambda i: jnp.minimum(t_min[..., None] + width * i.astype(jnp.float32), far)
  return jnp.where(valid, edge(first), far), jnp.where(valid, edge(last + 1), far), valid


def slot_candidates(occupied, num_samples):
  """Which occupied candidates each of K slots spans (see the module docstring).

  occupied: bool [..., M]. num_samples: int K.
  Returns (first, last, valid): int32 [..., K] candidates (slot k spans candidate first_k's
  start to candidate last_k's end) and bool [..., K], the slots that hold any.
  """
  n = jnp.sum(occupied, axis=-1, dtype=jnp.int32)[..., None]  # [..., 1]
  slots = jnp.arange(num_samples, dtype=jnp.int32)
  # Integer group bounds: slot k holds ranks [first_k, next_k) of max(n, K) ranks.
  per = jnp.maximum(n, num_samples)
  first = slots * per // num_samples
  last = jnp.minimum((slots + 1) * per // num_samples - 1, n - 1)
  held_by = _candidates_of_ranks(occupied, jnp.concatenate([first, last], axis=-1))
  return held_by[..., :num_samples], held_by[..., num_samples:], first < n


def occupied_slots(edges, occupied, num_samples, t_max):
  """The occupied candidates of each ray dealt into K slots (see the module docstring).

  edges: float32 [..., M + 1], sorted edges of M candidate intervals. occupied: bool [..., M],
  the candidates whose cell is occupied. num_samples: int K. t_max: float32 [...], the end of
  the ray's segment, where invalid slots sit.
  Returns (starts, ends, valid) as `sample_occupied`; invalid slots are [t_max, t_max].
  """
  first, last, valid = slot_candidates(occupied, num_samples)
  far = t_max[..., None]
  starts = jnp.where(valid, jnp.take_along_axis(edges[..., :-1], first, axis=-1), far)
  ends = jnp.where(valid, jnp.take_along_axis(edges[..., 1:], last, axis=-1), far)
  return starts, ends, valid


def computed_once(distances):
  """distances float32 [..., S], sorted along the last axis (placed samples), unchanged, but
  computed once: readers of the placed samples call it before querying a field at them.

  Without it XLA's CPU compiler fuses the placement (the edges of each slot's candidates, and
  the ray-box cut before them) into every consumer, so each of the grids' 8 corner gathers per
  level, forward and backward, recomputes it: measured on configs/detail.py (when the ranks
  were listed by nonzero), a train step took 332 ms instead of 174. A sort is not fused into
  its consumers (an optimisation barrier is dropped before fusion), and sorting values already
  in order returns them as they are. A compacting gather (a sample budget) is the one consumer
  itself and needs no sort.
  """
  return jnp.sort(distances, axis=-1)


def interleave_gaps(starts, ends, t_max):
  """Edges float32 [..., 2K + 1] of slots and the gaps between them: s_0, e_0, s_1, e_1, …, t_max.

  Interval 2k is slot k and interval 2k + 1 the (empty) gap after it.
  """
  pairs = jnp.stack([starts, ends], axis=-1).reshape(*starts.shape[:-1], -1)
  return jnp.concatenate([pairs, t_max[..., None]], axis=-1)


def with_gaps(values, axis=-1):
  """Each slot's value followed by a zero (its gap) along `axis`: [..., K, ...] -> [..., 2K, ...]."""
  axis = axis % values.ndim
  pairs = jnp.stack([values, jnp.zeros_like(values)], axis=axis + 1)
  return pairs.reshape(*values.shape[:axis], -1, *values.shape[axis + 1:])
