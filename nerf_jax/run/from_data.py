"""The config completed from the data, once, before anything is built: the background of the
data's family (data.background = 'auto'), the world centred on
what the cameras look at (data.focus), the scene's extent (data.scene_bound = -1), the grids'
box in NDC and from the visual hull, the ray bounds and pixel centres; and the one line that
warns when the scene box cuts the training rays (`cut_share`, which auto reads too).
"""

import jax.numpy as jnp
import ml_collections
import numpy as np

from nerf_jax.data import loaders
from nerf_jax.samplers import visual_hull
from nerf_jax.cameras.rays import pixel_rays, ray_box_bounds
from nerf_jax.run import photo_zoom
from nerf_jax.run.auto import characterise


def with_background(config):
  """`config` with data.background = 'auto' resolved to the convention of the data's family
  (loaders.auto_background: white for Blender's RGBA folders, else black), and one line saying
  which and why; the value is recorded in config.json (and metrics.json); `config` itself when
  data.background is not 'auto'."""
  if not loaders.is_auto(config.data.background):
    return config
  name, why = loaders.auto_background(config.data.path)
  config = ml_collections.ConfigDict(config.to_dict())
  config.data.background = name
  print(f"background: {name}, {why} (data.background='auto')", flush=True)
  return config


def with_focus(config, train_ds, test_ds):
  """(train_ds, test_ds) moved with data.focus so that the training cameras' focus point
  (characterise.focus_point: the point nearest their optical axes) is the origin, where the
  scene box (and a contraction's inner region) is centred: nerfstudio's 'focus' centring. The
  world moves, nothing turns or scales: poses, the data's boxes (aabb, core) and true poses
  move alike; depths and the near/far bounds (z-depths) stay. One line says where the point
  was; the datasets as they are without data.focus, in NDC (the frame is the cameras') or
  with data.subject (run/subject.py: the subject's centre is the origin already)."""
  if not config.data.focus or config.data.ndc or config.data.subject:
    return train_ds, test_ds
  point = characterise.focus_point(train_ds.poses, train_ds.near, train_ds.far)
  print(f"focus: the cameras look at ({', '.join(f'{v:.3g}' for v in point)}); the world is "
        "moved to put it at the origin, the centre of the scene box (data.focus)", flush=True)
  point = np.asarray(point, np.float32)  # as the poses are stored: a move in float32
  return train_ds.moved(point), test_ds.moved(point)


def scene_box(contraction, dataset):
  """(bound, why): the half-size of the scene box centred on the origin that data.scene_bound
  = -1 resolves to, and the phrase saying where it came from. With `contraction` (an unbounded
  scene) the inner box is the subject's (Dataset.core: instant-ngp's unit cube, or the sparse
  points' box), else the cameras'; in a bounded one it is the data's whole box (Dataset.aabb:
  instant-ngp's aabb_scale or the sparse points), else the cameras'."""
  box = dataset.core if contraction else dataset.aabb
  if box is None:
    return float(np.max(np.abs(dataset.poses[:, :3, 3]))), "the cameras' box"
  why = "the subject's box (core)" if contraction else "the data's box (aabb)"
  return float(np.max(np.abs(box))), why


def with_scene_extent(config, dataset):
  """`config` with data.scene_bound = -1 (auto) resolved from the data (`scene_box`), one line
  saying how. The value (and the grids' box, model.grid_bound) is recorded in config.json."""
  if config.data.scene_bound != -1:
    return config
  bound, why = scene_box(config.data.contraction, dataset)
  config = ml_collections.ConfigDict(config.to_dict())
  config.data.scene_bound = round(bound, 4)
  config.model.grid_bound = round(bound, 4)  # a bounded scene's grids cover the box found
  beyond = f", contracted ({config.data.contraction}) beyond" if config.data.contraction else ""
  centre = " about the cameras' focus (data.focus)" if config.data.focus else ""
  print(f"scene extent: box ±{bound:.3g} from {why}{centre}{beyond} (data.scene_bound)",
        flush=True)
  return config


NDC_MARGIN = 0.02  # share of each side added around the training rays' NDC box


def with_ndc_box(config, dataset, near, far):
  """`config` with the grid encodings' box (model.grid_box) found from the data in an NDC run
  that sets none: the box of every training ray's ends in NDC (t = 0 on the near plane and
  t = 1 at infinity), NDC_MARGIN wider on each side, so no photo's frustum is cut, and no cells
  are spent beyond them; an occupancy grid in NDC covers the same box, whatever the encoding.
  One line says so; the box is recorded in config.json."""
  m = config.model
  boxed = m.encoding not in ("posenc", "ipe") or config.occupancy.enabled
  if not config.data.ndc or not boxed or m.grid_box:
    return config
  # A pinhole camera maps its pixel grid projectively onto any plane, so the NDC ends of its
  # rays span the quadrilateral of its corner pixels' rays.
  i = jnp.array([0.0, dataset.width - 1.0, 0.0, dataset.width - 1.0])
  j = jnp.array([0.0, 0.0, dataset.height - 1.0, dataset.height - 1.0])
  ends = []
  for pose in dataset.poses:
    rays = pixel_rays(i, j, dataset.height, dataset.width, dataset.intrinsics, pose, near, far,
                      pixel_center(config, dataset), use_ndc=True)
    ends += [np.asarray(rays.origins), np.asarray(rays.origins + rays.directions)]
  ends = np.concatenate(ends)
  low, high = ends.min(axis=0), ends.max(axis=0)
  pad = NDC_MARGIN * (high - low)
  low, high = np.maximum(low - pad, -1e3), np.minimum(high + pad, 1e3)
  config = ml_collections.ConfigDict(config.to_dict())
  config.model.grid_box = tuple(round(float(v), 4) for v in (*low, *high))
  corner = lambda c: "(" + ", ".join(f"{float(v):.3f}" for v in c) + ")"
  print(f"NDC extent: the training rays span {corner(low)} to {corner(high)}; the grids cover "
        "it (model.grid_box)", flush=True)
  return config


HULL_RESOLUTION = 64  # cells per side of the carved grid when no occupancy grid sets it


def with_visual_hull(config, dataset):
  """(config, hull): with data.visual_hull on data with opacity, the training masks are carved
  (visual_hull.py) on the occupancy grid's cells (else 64^3 cells of the grids' cube), the grid
  encodings' box (model.grid_box, recorded in config.json) becomes the hull's bounding box and
  `hull` (float32 [R, R, R], bound: the scene box's) is returned for the occupancy grid; on a
  photo collection whose masks keep the subject (data.subject on), `subject_hull`; else
  (config, None)."""
  if not config.data.visual_hull:
    return config, None
  if dataset.masks is not None and config.data.subject:  # masks that keep the subject
    return config, subject_hull(dataset, config.data.scene_bound, pixel_center(config, dataset))
  if dataset.accs is None or config.data.contraction:
    why = "the data has no opacity" if dataset.accs is None else "the scene is unbounded"
    print(f"note: data.visual_hull is ignored: {why}", flush=True)
    return config, None
  dataset = dataset.one_camera()  # per-image cameras: carved from image 0's camera's views
  occupied = config.occupancy.enabled
  bound = config.data.scene_bound if occupied else config.model.grid_bound
  resolution = config.occupancy.resolution if occupied else HULL_RESOLUTION
  hull = visual_hull.carve(dataset.accs, dataset.poses, dataset.intrinsics, bound, resolution,
                           pixel_center(config, dataset), masks=dataset.masks)
  box = visual_hull.bounding_box(hull, bound)
  config = ml_collections.ConfigDict(config.to_dict())
  config.model.grid_box = tuple(round(float(v), 4) for v in box.reshape(-1))
  share = float(np.mean(np.asarray(hull)))
  corner = lambda c: "(" + ", ".join(f"{float(v):.3f}" for v in c) + ")"
  print(f"visual hull: {100 * share:.1f}% of the box's cells; the grids cover "
        f"{corner(box[0])} to {corner(box[1])} (model.grid_box)", flush=True)
  return config, (hull, bound) if occupied else None


HULL_VOTE = 0.6  # a subject's hull keeps a cell that 60% of the photos seeing it keep (landmark,
#   its stored pinhole: 0.8 carves 3% of the monument, 0.6 none)
SUBJECT_HULL_EXTENT = 2.0  # a subject's hull covers twice the box found for it: found from
#   photos whose stored camera lacks their zoom, that box leaves 25% of landmark's monument out
SUBJECT_HULL_CELLS = 96  # cells per side of a subject's hull (0.04 of the box's half-size)


def subject_hull(dataset, bound, pixel_center):
  """(float32 [R, R, R], its half-size): the hull of masks that keep the subject
  (visual_hull.carve_vote with HULL_VOTE) on SUBJECT_HULL_CELLS^3 cells of the box
  SUBJECT_HULL_EXTENT times the box [-bound, bound]^3 the subject was found to fill
  (run/subject.py); the renderers give no density in the cells it carves nor outside it. One
  line says how much it keeps."""
  extent = SUBJECT_HULL_EXTENT * bound
  hull = visual_hull.carve_vote(dataset.masks, dataset.poses, dataset.cameras, extent,
                                SUBJECT_HULL_CELLS, HULL_VOTE, pixel_center)
  print(f"visual hull: {100 * float(np.mean(hull)):.1f}% of the box ±{extent:g} about the "
        f"subject, where {100 * HULL_VOTE:.0f}% of the photos that see a cell keep it; no "
        "density outside it (data.visual_hull)", flush=True)
  return jnp.asarray(hull), extent


def with_photo_zoom(config, dataset):
  """`dataset` (the training views, moved by data.subject) with data.photo_zoom on: a camera per
  photo, each focal fitted to the photo's mask against the masks' hull over the box a subject's
  hull covers (run/photo_zoom.py); as given when off. ValueError where nothing marks the
  subject to fit against (masks and data.subject on, photos of one size)."""
  if not config.data.photo_zoom:
    return dataset
  if dataset.masks is None or not config.data.subject or dataset.mixed_sizes:
    raise ValueError("config.data.photo_zoom: fits each photo's focal to masks that keep the "
                     "subject: it needs data.subject on, masks and photos of one size")
  return photo_zoom.with_photo_zoom(dataset, SUBJECT_HULL_EXTENT * config.data.scene_bound,
                                    HULL_VOTE, pixel_center(config, dataset))


CUT_SHARE = 0.25  # a run warns when more training rays than this leave the box before far


VIEWS_CHECKED, RAYS_PER_SIDE = 8, 16  # cut_share looks at 16 x 16 rays of ~8 views


def cut_share(dataset, bound, near, far, pixel_center):
  """The share of training rays that leave the box [-bound, bound]^3 before 0.95 of their far
  bound (RAYS_PER_SIDE^2 rays evenly over each of ~VIEWS_CHECKED views); None where the data has
  opacity (RGBA files, the built-in scenes): it says where the scene is empty, so nothing is cut.

  dataset: the training Dataset. bound: float > 0. near, far: float, the rays' z-depth bounds.
  pixel_center: float, where in its pixel each ray passes (`pixel_center`).
  """
  if dataset.accs is not None:
    return None
  poses = dataset.poses
  cut = []
  for k in range(0, len(poses), max(1, len(poses) // VIEWS_CHECKED)):
    height, width, intrinsics = dataset.cameras.camera(k)
    i, j = np.meshgrid(np.linspace(0, width - 1, RAYS_PER_SIDE, dtype=np.float32),
                       np.linspace(0, height - 1, RAYS_PER_SIDE, dtype=np.float32))
    rays = pixel_rays(jnp.asarray(i), jnp.asarray(j), height, width, intrinsics, poses[k], near,
                      far, pixel_center)
    t_far = ray_box_bounds(rays.origins, rays.directions, bound, rays.near, rays.far)[1]
    cut.append(np.mean(np.asarray(t_far) < 0.95 * np.asarray(rays.far)))
  return float(np.mean(cut))


def warn_if_cut(exp):
  """One line when more than CUT_SHARE of the training rays leave the scene box before their
  far bound (`cut_share`): what lies beyond is cut from the model (a bounded box on a real
  capture). --config=auto reads the same share and contracts the space beyond the box instead
  (the contraction rule, run/auto/rules/contraction.py), so it never gets this line on its own
  choice."""
  sampler = exp.renderer.sampler
  if sampler.scene_bound <= 0 or sampler.contraction or exp.config.data.ndc:
    return
  share = cut_share(exp.train_ds, sampler.scene_bound, exp.near, exp.far, exp.pixel_center)
  if share is not None and share > CUT_SHARE:
    print(f"note: {100 * share:.0f}% of training rays leave the scene box "
          f"(±{sampler.scene_bound:g}) before their far bound ({exp.far:.3g}): what lies "
          "beyond is not modelled; for a garden or a street set data.contraction='linf' "
          "(docs/real_captures.md), or data.scene_bound=-1 (the box from the data)", flush=True)


def pixel_center(config, dataset):
  """config.data.pixel_center, or with -1 the dataset's (what its images were taken through);
  ValueError naming the field for any other value outside [0, 1]."""
  value = config.data.pixel_center
  if value == -1:
    return float(dataset.pixel_center)
  if not 0.0 <= value <= 1.0:
    raise ValueError(f"config.data.pixel_center={value}: use -1 (the data's own), 0 (pixel "
                     "corners) or 0.5 (pixel centres)")
  return float(value)


def bounds(config, dataset):
  """(near, far): [0, 1] in NDC, else the config's overrides where set, else the dataset's."""
  if config.data.ndc:
    return 0.0, 1.0  # NDC rays run from the near plane (0) to infinity (1)
  return (float(config.data.near or dataset.near), float(config.data.far or dataset.far))
