"""The subject's extent, read from the data, and the world scaled and moved so that the subject
fills the inner region (data.subject): what NeRF-W (per-photo near/far from the sparse points'
depths) and K-Planes (the landmark scaled into the uncontracted region) do for photo
collections, where the cameras' box is many times the subject's.

Names (numpy, world units):
  centre, half: float64 [3], the subject's box: its centre and its half-extent on each axis;
  poses: float [N, 4, 4] camera-to-world (a camera looks down its -z axis, cameras/rays.py);
  region: (centre float64 [3], half float) the cube carved when the box is found by carving.

The sources, in the order `subject_box` tries them:
  masks   masks that keep a subject (Dataset.masks): where at least MASK_VOTE of the photos
          that see a point (MASK_SEEN of all) keep its pixel (carved; visual_hull.mask_votes,
          each photo through its own camera; cells wider than the subject, where photos from
          far away widen the region, located by their footprints first: `carve`), if that is
          far smaller than the cameras' region (masks of passers-by keep nearly everything);
  points  the sparse points (Dataset.points): their POINT_PERCENTILE..(100 - it) percentiles;
  bounds  each image's (near, far) depths (Dataset.bounds, LLFF's): where every camera's depth
          slab holds a point (the slabs' intersection, carved);
  focus   else the cameras: centred on their focus point, out to the farthest camera
          (today's box about data.focus).
  box     by hand (data.subject_box), as K-Planes sizes each scene; never tried by 'auto'.
Masks come first: they say which pixels are the subject, while structure from motion matches
whatever the photos share, the square, the façades and the crowd as much as the monument, and
LLFF's bounds are those points' depths. Where masks mark no subject they are passed over.
"""

import dataclasses

import ml_collections
import numpy as np

from nerf_jax.data.dataset import DataError
from nerf_jax.run.auto import characterise
from nerf_jax.samplers import visual_hull

POINT_PERCENTILE = 1.0  # the points' box: their 1st to 99th percentiles on each axis
CARVE_CELLS = 48  # cells per side of a carved grid; carved twice, the second time on the box found
MAX_ZOOMS = 4  # a subject smaller than the cells: located by their footprints, each time on a
#   grid over the cells touched and two around them, at most this often
MASK_VOTE = 0.8  # a point is the subject where 80% of the photos that see it keep it (not all:
#   passers-by hide parts of it, per-photo zoom that the stored camera lacks shifts its edges;
#   landmark at 48 px, 60 views: 0.8 finds its box within 0.11 clean, 0.22 from the photos)
MASK_SEEN = 0.5  # ... and at least half of all photos see it (not a point a few photos see)
MASK_SUBJECT = 0.5  # masks mark a subject when its box is under half the carved region's size
MARGIN = 1.1  # the subject's largest half-extent times this fills the inner region
MIN_NEAR = 1e-3  # a camera inside the subject's box: its near bound stays positive
SOURCES = ("auto", "masks", "points", "bounds", "focus", "box")  # data.subject's values besides ''


@dataclasses.dataclass(frozen=True)
class SubjectBox:
  centre: np.ndarray  # float64 [3]
  half: np.ndarray  # float64 [3], half-extent per axis
  source: str  # 'masks', 'points', 'bounds', 'focus' or 'box'


def cameras_region(dataset):
  """(centre float64 [3], half float): the cube about the cameras' focus point
  (characterise.focus_point) out to the farthest camera coordinate from it."""
  centre = characterise.focus_point(dataset.poses, dataset.near, dataset.far)
  half = float(np.max(np.abs(np.asarray(dataset.poses)[:, :3, 3] - centre)))
  return centre, half


def from_points(points):
  """SubjectBox of the points float [P, 3]: their POINT_PERCENTILE to (100 - it) percentiles on
  each axis (outliers dropped); None for fewer than 4 points."""
  if points is None or len(points) < 4:
    return None
  lo, hi = np.percentile(np.asarray(points, np.float64),
                         [POINT_PERCENTILE, 100 - POINT_PERCENTILE], axis=0)
  return SubjectBox(0.5 * (lo + hi), 0.5 * (hi - lo), "points")


def _grid(centre, half, cells):
  """float64 [cells^3, 3]: the cell centres of the box centre ± half (half float [3])."""
  axes = [c + h * (2 * (np.arange(cells) + 0.5) / cells - 1) for c, h in zip(centre, half)]
  return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def carve(keep, region, cells=CARVE_CELLS, touch=None):
  """(lo, hi) float64 [3] of the cells `keep` keeps, carved twice: on `region`, then on the kept
  cells' box grown by two cells, each box grown by half a cell; None when nothing is kept.
  keep: function of points float64 [M, 3] -> bool [M]. touch: None, or a function of (points,
  reach: a cell's circumscribed radius) -> bool [M], whether what `keep` keeps may touch each
  point's cell: where a grid keeps no cell centre (a subject smaller than its cells, seen from
  far away), the cells `touch` keeps give the next grid instead, at most MAX_ZOOMS times."""
  centre, half = np.asarray(region[0], np.float64), np.full(3, float(region[1]))
  carved, zooms = 0, 0
  while carved < 2:
    points, cell = _grid(centre, half, cells), 2 * half / cells
    chosen = keep(points)
    if chosen.any():
      carved += 1
    elif touch is not None and zooms < MAX_ZOOMS:
      chosen, zooms = touch(points, 0.5 * float(np.linalg.norm(cell))), zooms + 1
    if not chosen.any():
      return None
    kept = points[chosen]
    lo, hi = kept.min(0) - 0.5 * cell, kept.max(0) + 0.5 * cell
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + 2 * cell
  return lo, hi


def depths(points, poses):
  """float64 [N, M]: the z-depth of each point float [M, 3] in each camera."""
  poses = np.asarray(poses, np.float64)
  rel = np.asarray(points)[None] - poses[:, None, :3, 3]
  return -np.einsum("nmi,ni->nm", rel, poses[:, :3, 2])


def from_bounds(poses, bounds, region):
  """SubjectBox where every camera's depth slab (its bounds float [N, 2], near and far) holds a
  point, carved in `region`; None when no point is in all of them."""
  bounds = np.asarray(bounds, np.float64)
  def keep(points):
    z = depths(points, poses)
    return np.all((z >= bounds[:, :1]) & (z <= bounds[:, 1:]), axis=0)
  box = carve(keep, region)
  return None if box is None else SubjectBox(0.5 * (box[0] + box[1]), 0.5 * (box[1] - box[0]),
                                             "bounds")


def from_masks(dataset, region):
  """SubjectBox where at least MASK_VOTE of the photos that see a point (at least MASK_SEEN of
  them all) keep its pixel (visual_hull.mask_votes: each photo through its own camera and size),
  carved in `region` (cells coarser than the subject: located by their footprints, `carve`), or
  the reason there is none (str): the masks keep no such region, or one at least MASK_SUBJECT of
  the region's size on its largest axis (masks of passers-by, not of a subject)."""
  cameras = dataset.cameras
  def vote(points, radius):
    seen, kept = visual_hull.mask_votes(dataset.masks, dataset.poses, cameras, points, radius,
                                        dataset.pixel_center)
    return (seen >= MASK_SEEN * len(dataset)) & (kept >= MASK_VOTE * seen)
  def touch(points, reach):  # a photo keeps a cell where its mask keeps a pixel of its footprint
    return vote(points, lambda k, depth: visual_hull.footprint_radius(reach, cameras.camera(k),
                                                                      depth))
  box = carve(lambda points: vote(points, lambda k, depth: 0), region, touch=touch)
  if box is None:
    return (f"no point that {100 * MASK_SEEN:.0f}% of the photos see is kept by "
            f"{100 * MASK_VOTE:.0f}% of those that see it (the masks agree on no subject)")
  share = float(np.max(box[1] - box[0])) / (2 * region[1])
  if share >= MASK_SUBJECT:
    return (f"the region they keep spans {100 * share:.0f}% of the cameras' region (>= "
            f"{100 * MASK_SUBJECT:.0f}%): masks of passers-by, not of a subject")
  return SubjectBox(0.5 * (box[0] + box[1]), 0.5 * (box[1] - box[0]), "masks")


def from_hand(box):
  """SubjectBox of `box` (data.subject_box: x, y, z centre then x, y, z half-extent); ValueError
  naming the field unless it holds six numbers with positive half-extents."""
  values = np.asarray(box, np.float64).reshape(-1)
  if values.shape != (6,) or not np.all(np.isfinite(values)) or np.any(values[3:] <= 0):
    raise ValueError(f"config.data.subject_box={tuple(box)!r}: give the subject's centre and "
                     "half-extent, six numbers (x, y, z, hx, hy, hz), each half-extent > 0")
  return SubjectBox(values[:3], values[3:], "box")


def subject_box(dataset, source="auto", box=()):
  """SubjectBox of the training views `dataset` (a Dataset) from `source` (module docstring):
  'auto' tries masks, points, bounds, then the cameras' focus; a named source gives None where
  the data lacks it ('focus' never does); 'box' is `box` (data.subject_box) by hand."""
  return find_box(dataset, source, box)[0]


def find_box(dataset, source="auto", box=()):
  """(SubjectBox or None, [why]): `subject_box`'s box and, for each source passed over, why
  ('masks: ...'). DataError naming the source where the box found has no extent on any axis
  (sparse points all at one place, cameras all at one place)."""
  if source == "box":
    return from_hand(box), []
  region = cameras_region(dataset)
  finders = {
      "masks": lambda: "the data has no masks" if dataset.masks is None else from_masks(
          dataset, region),
      "points": lambda: from_points(dataset.points) or "the data has no sparse points (or under 4)",
      "bounds": lambda: ("the data has no per-image bounds (Dataset.bounds)"
                         if dataset.bounds is None else
                         from_bounds(dataset.poses, dataset.bounds, region) or
                         "no point lies within every camera's bounds"),
      "focus": lambda: SubjectBox(region[0], np.full(3, region[1]), "focus"),
  }
  reasons = []
  for name in (finders if source == "auto" else (source,)):
    found = finders[name]()
    if isinstance(found, SubjectBox):
      if not np.max(found.half) > 0:
        raise DataError(f"{dataset.name or 'the data'}: the subject's box from the {name} has "
                        "no extent (half-extent 0 on every axis); give data.subject_box by "
                        "hand (data.subject='box')")
      return found, reasons
    reasons.append(f"{name}: {found}")
  return None, reasons


def subject_bounds(poses, half):
  """float32 [N, 2]: each camera's (near, far) z-depths of the box ± half (half float [3],
  centred at the origin), near at least MIN_NEAR."""
  corners = np.stack(np.meshgrid(*[[-h, h] for h in half], indexing="ij"), -1).reshape(-1, 3)
  z = depths(corners, poses)
  return np.stack([np.maximum(z.min(1), MIN_NEAR), np.maximum(z.max(1), 2 * MIN_NEAR)],
                  -1).astype(np.float32)


def with_subject(config, train_ds, test_ds):
  """(config, train_ds, test_ds) with data.subject on: the world moved and scaled (Dataset.moved) so
  that the subject's box (`subject_box` of the training views) is centred at the origin with
  its largest half-extent times MARGIN at data.scene_bound (1 where that is 0 or -1; -1 then
  becomes 1, as the box found); each training photo's bounds (Dataset.bounds) cover the
  subject's box from it, and near, far cover those of every photo; with data.photo_bounds the
  held-out views get theirs too (each view is then sampled within its own). One line says the
  source, the box and the scale. As given with '' or in NDC (the cameras' frame)."""
  source = config.data.subject
  if not source or config.data.ndc:
    return config, train_ds, test_ds
  if source not in SOURCES:
    raise ValueError(f"config.data.subject={source!r}: use '' (off) or one of {SOURCES}")
  box, reasons = find_box(train_ds, source, config.data.subject_box)
  if box is None:
    raise ValueError(f"config.data.subject={source!r}: no subject's box from the {reasons[0]} "
                     "(use 'auto')")
  bound = config.data.scene_bound if config.data.scene_bound > 0 else 1.0
  scale = bound / (MARGIN * float(np.max(box.half)))
  train_ds, test_ds = (d.moved(box.centre, scale) for d in (train_ds, test_ds))
  train_ds = with_bounds(train_ds, scale * box.half)
  if config.data.photo_bounds:  # the held-out views sampled as the photos are
    test_ds = with_bounds(test_ds, scale * box.half)
  if config.data.scene_bound == -1:
    config = ml_collections.ConfigDict(config.to_dict())
    config.data.scene_bound = config.model.grid_bound = bound
  fmt = lambda v: "(" + ", ".join(f"{x:.3g}" for x in v) + ")"
  print(f"subject: from the {box.source}, centre {fmt(box.centre)}, half-extent "
        f"{fmt(box.half)}; the world moved by {fmt(-box.centre)} and scaled by {scale:.4g} to "
        f"fill ±{bound:g} (data.subject); near {train_ds.near:.3g}, far {train_ds.far:.3g}",
        flush=True)
  return config, train_ds, test_ds


def with_bounds(dataset, half):
  """`dataset` (moved: the subject's box ± half at the origin) with each photo's bounds covering
  the box (and the photo's own bounds where it has them) and near, far covering every photo's."""
  own = subject_bounds(dataset.poses, half)
  if dataset.bounds is not None:
    own = np.stack([np.minimum(own[:, 0], dataset.bounds[:, 0]),
                    np.maximum(own[:, 1], dataset.bounds[:, 1])], -1)
  return dataclasses.replace(dataset, bounds=own, near=min(dataset.near, float(own[:, 0].min())),
                             far=max(dataset.far, float(own[:, 1].max())))
