"""The subject's box from each source the data may hold (run/subject.py), checked against a known
box BOX_LO..BOX_HI off the origin: sparse points sampled in it (with outliers), LLFF-style
per-camera depth bounds and masks computed from it here; then the world scaled and moved so
that the box fills the inner region exactly, and data.subject='' leaving the datasets alone."""

import dataclasses

import ml_collections
import numpy as np
import pytest

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data.dataset import DataError, Dataset
from nerf_jax.run import config_lib, from_data, subject
from nerf_jax.run.auto import auto
from nerf_jax.run.auto.rules import contraction, subject_box, transients
from nerf_jax.samplers import occupancy, visual_hull
from tests.helpers import small_config

BOX_LO, BOX_HI = np.array([1.0, -2.5, 0.5]), np.array([1.8, -1.3, 1.7])  # half (0.4, 0.6, 0.6)
CENTRE, HALF = 0.5 * (BOX_LO + BOX_HI), 0.5 * (BOX_HI - BOX_LO)
SIZE, FOCAL = 64, 60.0  # masks' pixels a side, focal in pixels


def _look_at(centre, target):
  """float64 [4, 4] camera-to-world at `centre` looking down -z at `target` (rays.py axes)."""
  back = (centre - target) / np.linalg.norm(centre - target)
  up = np.array([0.0, 0.0, 1.0]) if abs(back[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
  right = np.cross(up, back) / np.linalg.norm(np.cross(up, back))
  pose = np.eye(4)
  pose[:3, :3] = np.stack([right, np.cross(back, right), back], axis=1)
  pose[:3, 3] = centre
  return pose


def _sphere_cameras(num=40, distance=8.0):
  """float64 [num + 6, 4, 4]: cameras on a sphere about CENTRE (a Fibonacci spiral, and one on
  each axis), looking at it."""
  k = np.arange(num) + 0.5
  z = 1 - 2 * k / num
  phi = np.pi * (1 + 5 ** 0.5) * k
  dirs = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1)
  dirs = np.concatenate([dirs, np.eye(3), -np.eye(3)])
  return np.stack([_look_at(CENTRE + distance * d, CENTRE) for d in dirs])


def _corners(lo, hi):
  """float64 [8, 3], the corners of the box lo..hi."""
  return np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), -1).reshape(-1, 3)


def _dataset(poses, **fields):
  """A Dataset of blank SIZE x SIZE images from `poses`, near 1, far 20."""
  images = np.zeros((len(poses), SIZE, SIZE, 3), np.float32)
  return Dataset(images, poses.astype(np.float32), (FOCAL, FOCAL, SIZE / 2, SIZE / 2),
                 near=1.0, far=20.0, **fields)


def test_points_give_their_box_without_the_outliers():
  rng = np.random.default_rng(0)
  points = rng.uniform(BOX_LO, BOX_HI, (20000, 3))
  outliers = CENTRE + rng.normal(0.0, 30.0, (100, 3))  # 0.5%: beyond the percentiles
  box = subject.subject_box(_dataset(_sphere_cameras(), points=np.concatenate(
      [points, outliers]).astype(np.float32)))
  assert box.source == "points"
  # The 1st..99th percentiles of a uniform box lose 1% of its side at each end.
  np.testing.assert_allclose(box.centre, CENTRE, atol=0.02)
  np.testing.assert_allclose(box.half, 0.98 * HALF, atol=0.02)


def test_per_camera_depth_bounds_give_the_box():
  poses = _sphere_cameras()
  # Each camera's bounds: the z-depths of the box's corners, what COLMAP's points would give.
  rel = _corners(BOX_LO, BOX_HI)[None] - poses[:, None, :3, 3]
  z = -np.einsum("nmi,ni->nm", rel, poses[:, :3, 2])
  bounds = np.stack([z.min(1), z.max(1)], -1).astype(np.float32)
  box = subject.subject_box(_dataset(poses, bounds=bounds))
  assert box.source == "bounds"
  # The cameras on the axes make the slabs' intersection the box itself; carving finds it
  # within a cell of the second grid (box + 4 cells over 48).
  cell = 2 * (HALF.max() + 0.1) / subject.CARVE_CELLS
  np.testing.assert_allclose(box.centre, CENTRE, atol=cell)
  np.testing.assert_allclose(box.half, HALF, atol=cell)


def _box_masks(poses):
  """float32 [N, SIZE, SIZE]: 1 where a pixel's ray (through its centre) meets the box, by the
  slab test in the test's own code."""
  u, v = np.meshgrid(np.arange(SIZE) + 0.5, np.arange(SIZE) + 0.5, indexing="xy")
  cam = np.stack([(u - SIZE / 2) / FOCAL, -(v - SIZE / 2) / FOCAL, -np.ones_like(u)], -1)
  masks = []
  for pose in poses:
    d = cam @ pose[:3, :3].T
    with np.errstate(divide="ignore"):
      t0, t1 = (BOX_LO - pose[:3, 3]) / d, (BOX_HI - pose[:3, 3]) / d
    enter = np.minimum(t0, t1).max(-1)
    leave = np.maximum(t0, t1).min(-1)
    masks.append((leave >= max(enter.min(), 0.0)) & (leave >= enter))
  return np.stack(masks).astype(np.float32)


def test_masks_of_a_subject_give_its_box():
  poses = _sphere_cameras()
  box = subject.subject_box(_dataset(poses, masks=_box_masks(poses)))
  assert box.source == "masks"
  # A pixel at 8 units spans 8 / FOCAL = 0.13: the box holds the true one within a pixel's
  # footprint, and exceeds it by under 0.2 per side (the points outside that MASK_VOTE = 80% of
  # the views see against the box: 0.16 here, 0.07 with every view's vote).
  pixel = 8 / FOCAL
  np.testing.assert_allclose(box.centre, CENTRE, atol=pixel)
  assert np.all(box.half >= HALF - pixel) and np.all(box.half <= HALF + 0.2)


def test_masks_of_passers_by_mark_no_subject():
  poses = _sphere_cameras()
  masks = np.ones((len(poses), SIZE, SIZE), np.float32)
  masks[:, 20:40, 10:30] = 0.0  # a passer-by in every photo
  box = subject.subject_box(_dataset(poses, masks=masks))
  assert box.source == "focus"  # the cameras' region, today's box
  region = subject.cameras_region(_dataset(poses))
  np.testing.assert_allclose(box.half, region[1])


def _config(source, bound, box=(), photo_bounds=False):
  return ml_collections.ConfigDict({"data": {"subject": source, "scene_bound": bound,
                                             "ndc": False, "subject_box": box,
                                             "photo_bounds": photo_bounds},
                                    "model": {"grid_bound": 0.0}})


@pytest.mark.parametrize("bound", [-1.0, 2.0])
def test_the_box_fills_the_inner_region(bound):
  poses = _sphere_cameras()
  rng = np.random.default_rng(1)
  points = rng.uniform(BOX_LO, BOX_HI, (5000, 3)).astype(np.float32)
  train = _dataset(poses, points=points, depths=np.full((len(poses), SIZE, SIZE), 3.0,
                                                        np.float32))
  config, moved, test = subject.with_subject(_config("points", bound), train, train.subset([0]))
  target = 1.0 if bound == -1 else bound
  assert config.data.scene_bound == target
  box = subject.from_points(points)
  scale = target / (subject.MARGIN * box.half.max())
  # The box's corners, moved here by x -> scale (x - centre): inside ±target, the largest
  # half-extent at target / MARGIN, centred at the origin.
  corners = scale * (_corners(box.centre - box.half, box.centre + box.half) - box.centre)
  np.testing.assert_allclose(np.abs(corners).max(), target / subject.MARGIN, rtol=1e-6)
  np.testing.assert_allclose(corners.mean(0), 0.0, atol=1e-9)
  np.testing.assert_allclose(subject.from_points(moved.points).centre, 0.0, atol=1e-5)
  np.testing.assert_allclose(subject.from_points(moved.points).half, scale * box.half,
                             rtol=1e-5)
  np.testing.assert_allclose(moved.poses[:, :3, 3], scale * (poses[:, :3, 3] - box.centre),
                             atol=1e-5)
  np.testing.assert_allclose(moved.poses[:, :3, :3], poses[:, :3, :3], atol=1e-7)
  np.testing.assert_allclose(test.poses[0, :3, 3], moved.poses[0, :3, 3], atol=1e-6)
  np.testing.assert_allclose(moved.depths, 3.0 * scale, rtol=1e-6)
  # Each photo's bounds hold the moved box's corners; near, far hold every photo's bounds.
  z = -np.einsum("nmi,ni->nm", corners[None] - moved.poses[:, None, :3, 3],
                 moved.poses[:, :3, 2])
  np.testing.assert_allclose(moved.bounds, np.stack([z.min(1), z.max(1)], -1), rtol=1e-5)
  assert moved.near <= min(scale * 1.0, moved.bounds[:, 0].min())
  assert moved.far >= max(scale * 20.0, moved.bounds[:, 1].max())


def test_off_leaves_the_datasets_as_they_are():
  train = _dataset(_sphere_cameras(), points=np.zeros((10, 3), np.float32))
  config = _config("", -1.0)
  out = subject.with_subject(config, train, train)
  assert out[0] is config and out[1] is train and out[2] is train


def test_auto_fills_a_small_subject_of_a_collection_only():
  poses = _sphere_cameras(distance=8.0)  # half-extent 0.6 < 0.25 * 8
  masked = _dataset(poses, masks=_box_masks(poses))
  assert subject_box.subject_effects(masked, True)[0] == {"data.subject": "auto",
                                                   "data.contraction": contraction.CONTRACTION,
                                                   "data.photo_bounds": True,
                                                   "data.visual_hull": True,
                                                   "data.photo_zoom": True}
  assert subject_box.subject_effects(masked, True, "l2")[0] == {"data.subject": "auto",
                                                         "data.photo_bounds": True,
                                                         "data.visual_hull": True,
                                                         "data.photo_zoom": True}
  # a camera per photo (structure from motion fitted each focal): no zoom fitted again
  assert "data.photo_zoom" not in subject_box.subject_effects(masked, True, "l2", False)[0]
  rng = np.random.default_rng(2)  # sparse points mark it, no masks: the background trains
  points = rng.uniform(BOX_LO, BOX_HI, (2000, 3)).astype(np.float32)
  assert subject_box.subject_effects(_dataset(poses, points=points), True)[0] == {
      "data.subject": "auto", "data.contraction": contraction.CONTRACTION}
  assert subject_box.subject_effects(masked, False) == ({}, [])
  near = _sphere_cameras(distance=2.0)  # 0.6 >= 0.25 * 2: the subject fills the photos
  assert subject_box.subject_effects(_dataset(near, masks=_box_masks(near)), True)[0] == {}
  assert subject_box.subject_effects(_dataset(poses), True)[0] == {}  # nothing marks a subject


def test_a_box_by_hand_fills_the_inner_region_and_bounds_the_held_out_views():
  poses = _sphere_cameras()
  train, test = _dataset(poses[:30]), _dataset(poses[30:])
  box = tuple(CENTRE) + tuple(HALF)
  config, moved, moved_test = subject.with_subject(_config("box", 2.0, box, True), train, test)
  scale = 2.0 / (subject.MARGIN * HALF.max())
  np.testing.assert_allclose(moved.poses[:, :3, 3], scale * (poses[:30, :3, 3] - CENTRE),
                             atol=1e-5)
  assert config.data.scene_bound == 2.0
  # With data.photo_bounds the held-out views get their bounds too: the moved box's z-depths.
  corners = scale * (_corners(BOX_LO, BOX_HI) - CENTRE)
  for view, pose in zip(moved_test.bounds, moved_test.poses):
    z = -(corners - pose[:3, 3]) @ pose[:3, 2]
    np.testing.assert_allclose(view, [z.min(), z.max()], rtol=1e-5)
  assert subject.with_subject(_config("box", 2.0, box), train, test)[2].bounds is None


@pytest.mark.parametrize("box", [(), (0, 0, 0, 1, 1), (0, 0, 0, 1, 0, 1)])
def test_a_box_by_hand_must_be_six_numbers(box):
  with pytest.raises(ValueError, match="data.subject_box"):
    subject.with_subject(_config("box", -1.0, box), _dataset(_sphere_cameras()), None)


def test_a_misspelt_source_is_refused():
  with pytest.raises(ValueError, match="data.subject"):
    subject.with_subject(_config("mask", -1.0), _dataset(_sphere_cameras()), None)


def test_llff_keeps_each_views_bounds(tmp_path):
  from nerf_jax.data import llff  # pylint: disable=import-outside-toplevel
  poses = _sphere_cameras(num=4)[:4]
  bounds = np.array([[1, 5], [2, 6], [1.5, 7], [3, 9]], np.float32)
  llff.export_llff(dataclasses.replace(_dataset(poses), bounds=bounds), str(tmp_path))
  loaded = llff.load_llff(str(tmp_path))
  np.testing.assert_allclose(loaded.bounds, bounds)
  assert (loaded.near, loaded.far) == (1.0, 9.0)
  np.testing.assert_allclose(loaded.subset([1, 3]).bounds, bounds[[1, 3]])


def test_the_subject_move_scales_llffs_bounds_with_the_world(tmp_path):
  # An LLFF folder's per-view bounds (poses_bounds.npy: z-depths a little beyond the box's)
  # move with the world: without data.photo_bounds the held-out views keep theirs, and in the
  # moved world they are the z-depths the moved cameras measure to the moved box, times the same
  # margins; near and far scale alike.
  from nerf_jax.data import llff  # pylint: disable=import-outside-toplevel
  poses = _sphere_cameras(num=10)
  corners = _corners(BOX_LO, BOX_HI)
  depths = lambda poses, corners: -np.einsum("nmi,ni->nm", corners[None] - poses[:, None, :3, 3],
                                             poses[:, :3, 2])
  z = depths(poses, corners)
  bounds = np.stack([0.8 * z.min(1), 1.25 * z.max(1)], -1).astype(np.float32)
  llff.export_llff(dataclasses.replace(_dataset(poses), bounds=bounds), str(tmp_path))
  loaded = llff.load_llff(str(tmp_path))
  train, test = loaded.subset(range(12)), loaded.subset(range(12, len(loaded)))
  box = tuple(CENTRE) + tuple(HALF)
  _, _, moved_test = subject.with_subject(_config("box", 2.0, box), train, test)
  scale = 2.0 / (subject.MARGIN * HALF.max())
  z = depths(moved_test.poses, scale * (corners - CENTRE))
  np.testing.assert_allclose(moved_test.bounds, np.stack([0.8 * z.min(1), 1.25 * z.max(1)], -1),
                             rtol=1e-5)
  np.testing.assert_allclose(moved_test.bounds, scale * test.bounds, rtol=1e-6)
  assert moved_test.near == pytest.approx(scale * test.near)
  assert moved_test.far == pytest.approx(scale * test.far)


# A collection with a camera per photo (nerf-process --nosingle_camera): each photo its own size,
# focal and principal point, and (with far=True) every sixth photo taken from 4x as far through
# a 4x longer lens, so that the cameras' region is ±32 and its first carving grid's cells
# (1.3) are wider than the box (0.8 on x): the box's cells are located by their footprints.
SIZES = ((48, 64), (64, 48), (56, 56))  # (height, width) in turn
FAR = 4.0


def _own_cameras(poses, far=False):
  """(poses float64 [N, 4, 4], [(height, width, (fx, fy, cx, cy))]) of the collection above."""
  rng = np.random.default_rng(5)
  poses, cameras = poses.copy(), []
  for k in range(len(poses)):
    height, width = SIZES[k % len(SIZES)]
    focal = FOCAL * np.exp(rng.uniform(-0.4, 0.4))
    if far and k % 6 == 0:
      poses[k, :3, 3] = CENTRE + FAR * (poses[k, :3, 3] - CENTRE)
      focal *= FAR
    cameras.append((height, width, (focal, focal * 1.02, width / 2 + rng.uniform(-3, 3),
                                    height / 2 + rng.uniform(-3, 3))))
  return poses, cameras


def _box_mask(pose, camera):
  """float32 [H, W]: 1 where the ray through a pixel's centre, through `camera` ((height, width,
  (fx, fy, cx, cy)); y up, looking down -z), meets the box BOX_LO..BOX_HI ahead (slab test)."""
  height, width, (fx, fy, cx, cy) = camera
  u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5, indexing="xy")
  d = np.stack([(u - cx) / fx, -(v - cy) / fy, -np.ones_like(u)], -1) @ pose[:3, :3].T
  with np.errstate(divide="ignore", invalid="ignore"):
    t0, t1 = (BOX_LO - pose[:3, 3]) / d, (BOX_HI - pose[:3, 3]) / d
  enter, leave = np.minimum(t0, t1).max(-1), np.maximum(t0, t1).min(-1)
  return ((leave >= enter) & (leave > 0)).astype(np.float32)


def _own_dataset(far=False, **fields):
  """A Dataset of the collection above (images of three sizes: lists), its masks the box's."""
  poses, cameras = _own_cameras(_sphere_cameras(), far)
  masks = [_box_mask(p, c) for p, c in zip(poses, cameras)]
  return Dataset([np.zeros((h, w, 3), np.float32) for h, w, _ in cameras],
                 poses.astype(np.float32), cameras[0][2], near=1.0, far=40.0,
                 image_cameras=Cameras.stack(cameras), masks=masks, **fields), cameras


@pytest.mark.parametrize("far", [False, True])
def test_masks_through_each_photos_own_camera_give_the_box(far):
  dataset, cameras = _own_dataset(far)
  assert dataset.mixed_sizes and dataset.image_cameras is not None
  box = subject.subject_box(dataset)
  assert box.source == "masks"
  # The largest pixel footprint at the box (distance 8 or 32 over the focal) bounds the error,
  # as for one camera (test_masks_of_a_subject_give_its_box).
  pixel = max(np.linalg.norm(dataset.poses[k, :3, 3] - CENTRE) / c[2][0]
              for k, c in enumerate(cameras))
  np.testing.assert_allclose(box.centre, CENTRE, atol=pixel)
  assert np.all(box.half >= HALF - pixel) and np.all(box.half <= HALF + 0.2)
  # A projection written here: each photo keeps the box's centre, through its own camera.
  for pose, camera, mask in zip(dataset.poses, cameras, dataset.masks):
    local = (CENTRE - pose[:3, 3]) @ pose[:3, :3]
    (fx, fy, cx, cy) = camera[2]
    column = cx + fx * local[0] / -local[2] - 0.5
    row = cy - fy * local[1] / -local[2] - 0.5
    assert mask[int(round(row)), int(round(column))] == 1.0


def test_far_photos_make_the_first_grid_coarser_than_the_box():
  # What the footprints are for: the cells' centres alone keep nothing on the cameras' region.
  dataset, _ = _own_dataset(far=True)
  region = subject.cameras_region(dataset)
  assert 2 * region[1] / subject.CARVE_CELLS > 2 * HALF.min()
  def centres_kept(points):
    seen, kept = visual_hull.mask_votes(dataset.masks, dataset.poses, dataset.cameras, points,
                                        lambda k, depth: 0, dataset.pixel_center)
    return (seen >= subject.MASK_SEEN * len(dataset)) & (kept >= subject.MASK_VOTE * seen)
  assert subject.carve(centres_kept, region) is None
  assert subject.from_masks(dataset, region).source == "masks"


def test_masks_come_before_points_that_cover_the_square_too():
  rng = np.random.default_rng(6)
  # structure from motion's points: the monument, and the square and crowd around it
  points = np.concatenate([rng.uniform(BOX_LO, BOX_HI, (2000, 3)),
                           CENTRE + rng.uniform(-6.0, 6.0, (4000, 3)) * [1, 1, 0.1]])
  dataset, _ = _own_dataset(points=points.astype(np.float32))
  assert subject.from_points(dataset.points).half.max() > 4.0  # the square's, not the subject's
  box = subject.subject_box(dataset)
  assert box.source == "masks" and np.all(box.half <= HALF + 0.2)
  effects, lines = subject_box.subject_effects(dataset, True, "", stored_camera=False)
  assert effects == {"data.subject": "auto", "data.contraction": contraction.CONTRACTION,
                     "data.photo_bounds": True, "data.visual_hull": True}
  assert "the masks mark a subject" in lines[0]
  # Masks of passers-by mark no subject: the points come next.
  crowd = np.ones((len(dataset.poses), SIZE, SIZE), np.float32)
  crowd[:, 20:40, 10:30] = 0.0
  found, reasons = subject.find_box(_dataset(_sphere_cameras(), masks=crowd, points=points
                                             .astype(np.float32)))
  assert found.source == "points" and "passers-by" in reasons[0]


def test_the_subject_asked_from_masks_with_a_camera_per_photo_bounds_and_carves(monkeypatch):
  monkeypatch.setattr(from_data, "SUBJECT_HULL_CELLS", 48)  # 96 in a run: 8x the test's time
  photos, _ = _own_dataset()
  train, test = photos.subset(np.arange(0, len(photos), 3)), photos.subset([1, 2])
  config = small_config(base="capture", **{"data.subject": "masks", "data.photo_bounds": True,
                                           "data.visual_hull": True, "data.scene_bound": -1.0,
                                           "data.contraction": "linf"})
  config, moved, moved_test = subject.with_subject(config, train, test)
  box = subject.subject_box(train)
  scale = 1.0 / (subject.MARGIN * box.half.max())
  truth = scale * (_corners(BOX_LO, BOX_HI) - box.centre)  # the true box, moved
  # Each photo's bounds hold the true box's depths (the box found holds it within a pixel).
  for bounds in (moved.bounds, moved_test.bounds):
    poses = moved.poses if bounds is moved.bounds else moved_test.poses
    z = -np.einsum("nmi,ni->nm", truth[None] - poses[:, None, :3, 3], poses[:, :3, 2])
    assert np.all(bounds[:, 0] <= z.min(1) + 0.2 * scale)
    assert np.all(bounds[:, 1] >= z.max(1) - 0.2 * scale)
  _, (hull, extent) = from_data.with_visual_hull(config, moved)
  cells = np.asarray(occupancy.cell_centres(hull.shape[0], extent)).reshape(-1, 3)
  inside = np.all((cells >= truth.min(0)) & (cells <= truth.max(0)), axis=1)
  kept = np.asarray(hull).reshape(-1) > 0
  assert kept[inside].all()  # none of the subject carved
  outside = np.max(np.maximum(truth.min(0) - cells, cells - truth.max(0)), axis=1)
  # The photos rule out what lies well outside it; a 60% vote keeps cells just outside a face,
  # which most photos see against it (here up to 0.83 out, the box's half-extent 0.79).
  assert kept[outside > 0.5].mean() < 0.05 and not kept[outside > 1.0].any()


def test_a_source_that_gives_no_box_is_named_with_its_reason():
  poses = _sphere_cameras()
  with pytest.raises(ValueError, match="masks: the data has no masks"):
    subject.with_subject(_config("masks", -1.0), _dataset(poses), None)
  crowd = np.ones((len(poses), SIZE, SIZE), np.float32)
  crowd[:, 20:40, 10:30] = 0.0
  with pytest.raises(ValueError, match="passers-by"):
    subject.with_subject(_config("masks", -1.0), _dataset(poses, masks=crowd), None)


@pytest.mark.parametrize("source", ["points", "auto"])
def test_a_box_with_no_extent_is_a_one_line_error_naming_its_source(source):
  # every sparse point at one place (a broken point cloud): no scale fills a box of size 0
  train = _dataset(_sphere_cameras(), points=np.tile(CENTRE, (10, 1)).astype(np.float32))
  with pytest.raises(DataError, match="box from the points has no extent") as error:
    subject.with_subject(_config(source, -1.0), train, train)
  assert "\n" not in str(error.value)


def test_auto_measures_the_subject_on_the_photos_not_their_resampled_view(monkeypatch):
  # The other rules read one camera's view (Dataset.one_camera: every photo resampled into the
  # narrowest field of view); the subject is measured on the photos themselves.
  dataset, _ = _own_dataset()
  given = []
  monkeypatch.setattr(subject_box, "subject_effects",
                      lambda photos, *args: given.append(photos) or ({}, []))
  monkeypatch.setattr(transients, "transient_effects",
                      lambda *args: ({}, "no transients: not here"))
  auto.auto_config(config_lib.load("auto"), dataset, backend="cpu")
  assert dataset.one_camera().image_cameras is None  # what the other rules read
  assert len(given) == 1 and given[0] is dataset
