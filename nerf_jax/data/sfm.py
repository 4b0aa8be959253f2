"""Structure from motion with pycolmap (CPU): SIFT features, matching, incremental mapping.

pycolmap is the optional extra `capture` (`pip install -e ".[capture]"`); written against
pycolmap 4.x (`extract_features`, `match_exhaustive`, `match_sequential`,
`incremental_mapping`, `Image.cam_from_world()`).

Output conventions (`Reconstruction`): COLMAP's world frame and units; poses converted to
`cameras.rays`' camera-to-world with OpenGL axes (x right, y up, looking down -z); intrinsics
in COLMAP's pixel convention (`nerf_jax.data.lens`).
"""

import dataclasses
import os
import time

import numpy as np

from nerf_jax.data import lens
from nerf_jax.data.dataset import DataError

OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])  # camera axes: y down, z forward -> y up, z back


class SfmError(DataError):
  """Structure from motion failed or cannot run; the one-line message says what helps."""


def require_pycolmap():
  """The pycolmap module; SfmError naming the extra to install when it is missing."""
  try:
    import pycolmap  # pylint: disable=import-outside-toplevel
  except ImportError:
    raise SfmError('pycolmap is not installed: pip install -e ".[capture]" (or pip install '
                   "pycolmap)") from None
  return pycolmap


@dataclasses.dataclass
class Reconstruction:
  """What `reconstruct` recovered, for the registered images only (sorted by name).

  names: list of str, image file names. poses: float64 [N, 4, 4], camera-to-world, OpenGL axes.
  intrinsics: float64 [N, 4], (fx, fy, cx, cy) of each image, COLMAP pixel convention.
  dist: float64 [N, 4], (k1, k2, p1, p2). camera_ids: int [N], COLMAP camera of each image.
  size: (height, width) of the first image. points: float64 [P, 3]; colors: uint8 [P, 3];
  point_errors: float64 [P], reprojection error of each point in pixels. mean_error: float, over
  all observations. colmap: the pycolmap.Reconstruction itself. sizes: None (every image is
  `size`) or int [N, 2], (height, width) of each image (photos of several cameras).
  """
  names: list
  poses: np.ndarray
  intrinsics: np.ndarray
  dist: np.ndarray
  camera_ids: np.ndarray
  size: tuple
  points: np.ndarray
  colors: np.ndarray
  point_errors: np.ndarray
  mean_error: float
  colmap: object
  sizes: np.ndarray = None

  def image_sizes(self):
    """(height, width) of each image: int [N, 2]."""
    if self.sizes is None:
      return np.tile(np.asarray(self.size, int), (len(self.names), 1))
    return np.asarray(self.sizes, int)


def c2w_from_cam_from_world(matrix):
  """COLMAP's world-to-camera [R | t] (float [3, 4], OpenCV axes) -> float64 [4, 4]
  camera-to-world with OpenGL axes."""
  rot, trans = np.asarray(matrix, np.float64)[:, :3], np.asarray(matrix, np.float64)[:, 3]
  c2w = np.eye(4)
  c2w[:3, :3], c2w[:3, 3] = rot.T, -rot.T @ trans
  return c2w @ OPENCV_TO_OPENGL


def choose_matcher(matcher, num_images, ordered=False, video=False):
  """(matcher, why): 'exhaustive' or 'sequential' for matcher in ('auto', 'exhaustive',
  'sequential'), and one phrase saying why. 'auto' matches every pair of an unordered
  collection, whatever its count (its overlapping photos can be anywhere in it), and each image
  with its neighbours in file-name order only for an ordered capture: video frames (`video`)
  or photos the user says were taken in order (`ordered`)."""
  if matcher not in ("auto", "exhaustive", "sequential"):
    raise SfmError(f"--matcher={matcher}: expected auto, exhaustive or sequential")
  if matcher != "auto":
    return matcher, f"--matcher={matcher}"
  if video:
    return "sequential", "video frames: each matched with the frames near it in time"
  if ordered:
    return "sequential", "--ordered: each photo matched with its neighbours in file-name order"
  pairs = num_images * (num_images - 1) // 2
  return "exhaustive", (f"unordered photos: every pair of the {num_images} matched ({pairs:,} "
                        "pairs; --ordered for photos taken in order)")


def _stage(log, name, fn):
  start = time.perf_counter()
  log(f"  {name} ...")
  out = fn()
  seconds = time.perf_counter() - start
  log(f"  {name}: {seconds:.1f} s")
  return out, seconds


def reconstruct(image_dir, work_dir, matcher="exhaustive", camera_model="SIMPLE_RADIAL",
                single_camera=True, num_threads=-1, log=print):
  """Run SfM on every image in `image_dir`; keep the largest model.

  work_dir: str, gets COLMAP's database.db, every model in models/ and the largest in
  sparse/0 (where COLMAP tools and nerfstudio look). matcher: 'exhaustive' or 'sequential'
  (`choose_matcher`). camera_model: a key of `lens.COLMAP_PARAMS`. single_camera: one camera
  shared by all images (one device), else one per image. num_threads: -1 = all cores.
  Returns (Reconstruction or None if no model could be built, {stage: seconds}).
  """
  pycolmap = require_pycolmap()
  if camera_model not in lens.COLMAP_PARAMS:
    raise SfmError(f"--camera_model={camera_model}: expected one of "
                   f"{', '.join(lens.COLMAP_PARAMS)}")
  pycolmap.logging.minloglevel = 2  # COLMAP's INFO and WARNING lines; we print our own progress
  pycolmap.set_random_seed(0)  # RANSAC draws the same samples: a run can be repeated
  database = f"{work_dir}/database.db"
  reader = pycolmap.ImageReaderOptions()
  reader.camera_model = camera_model
  extraction = pycolmap.FeatureExtractionOptions()
  extraction.num_threads = num_threads
  mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.PER_IMAGE
  matching = pycolmap.FeatureMatchingOptions()
  matching.num_threads = num_threads
  mapping = pycolmap.IncrementalPipelineOptions()
  mapping.num_threads = num_threads
  device = pycolmap.Device.cpu
  times = {}
  _, times["features"] = _stage(log, "SIFT features", lambda: pycolmap.extract_features(
      database, image_dir, camera_mode=mode, reader_options=reader,
      extraction_options=extraction, device=device))
  match = pycolmap.match_exhaustive if matcher == "exhaustive" else pycolmap.match_sequential
  _, times["matching"] = _stage(log, f"{matcher} matching", lambda: match(
      database, matching_options=matching, device=device))
  models, times["mapping"] = _stage(log, "incremental mapping", lambda: (
      pycolmap.incremental_mapping(database, image_dir, f"{work_dir}/models", options=mapping)))
  if not models:
    return None, times
  best = max(models.values(), key=lambda m: m.num_reg_images())
  os.makedirs(f"{work_dir}/sparse/0", exist_ok=True)
  best.write(f"{work_dir}/sparse/0")
  return convert(best), times


def convert(model):
  """A pycolmap.Reconstruction -> `Reconstruction`."""
  images = sorted((im for im in model.images.values() if im.has_pose), key=lambda im: im.name)
  poses, intrinsics, dist = [], [], []
  for image in images:
    poses.append(c2w_from_cam_from_world(image.cam_from_world().matrix()))
    camera = model.cameras[image.camera_id]
    k, d = lens.from_colmap(camera.model.name, camera.params)
    intrinsics.append(k)
    dist.append(d)
  camera = model.cameras[images[0].camera_id]
  point_list = list(model.points3D.values())
  return Reconstruction(
      names=[im.name for im in images], poses=np.stack(poses), intrinsics=np.array(intrinsics),
      dist=np.array(dist), camera_ids=np.array([im.camera_id for im in images]),
      size=(camera.height, camera.width),
      points=np.array([p.xyz for p in point_list], np.float64).reshape(-1, 3),
      colors=np.array([p.color for p in point_list], np.uint8).reshape(-1, 3),
      point_errors=np.array([p.error for p in point_list], np.float64),
      mean_error=float(model.compute_mean_reprojection_error()), colmap=model,
      sizes=np.array([_size(model.cameras[im.camera_id]) for im in images], int))


def _size(camera):
  """(height, width) of a pycolmap camera."""
  return camera.height, camera.width
