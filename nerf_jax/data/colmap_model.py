"""COLMAP's sparse model files as they come: cameras, images (with each image's 2D points) and
points3D (with each point's error and track), all three binary (`.bin`) or all three text
(`.txt`), in COLMAP's documented formats (https://colmap.github.io/format.html), in DIR/sparse/0/
(or DIR/sparse/, DIR/colmap/sparse/0/). Pure numpy: pycolmap is not needed to read them.
Loading a COLMAP folder as a Dataset is colmap.py's; a model beside another loader's poses
(transforms.json, LLFF) gives its tracks through `beside`.

cameras: CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[] (binary: int32 id, int32 model id, uint64
  width, uint64 height, float64 params). Every COLMAP model parses (`MODELS`); which ones a
  loader reads is colmap.py's.
images: IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME, then the 2D points POINTS2D[]
  as (X, Y, POINT3D_ID) (binary: uint64 count, then float64, float64, int64 each; -1 = the
  keypoint sees no 3D point; `read_keypoints`): the rotation (a unit quaternion) and translation
  of world-to-camera with OpenCV axes (x right, y down, z forward); NAME is the file under
  DIR/images/.
points3D: POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX) (binary:
  uint64 id, 3 float64, 3 uint8, float64 error, uint64 track length, then (int32, int32) pairs):
  the sparse points, each one's mean reprojection error in pixels and the images that see it
  (`read_sparse_points`).
"""

import dataclasses
import os
import struct

import numpy as np

from nerf_jax.data import sfm
from nerf_jax.data.dataset import DataError

MODEL_DIRS = ("sparse/0", "sparse", "colmap/sparse/0")  # where a model is looked for, in order
FILES = ("cameras", "images", "points3D")
# COLMAP's camera model ids (src/colmap/sensor/models.h) -> (name, number of parameters): every
# model, so that a binary file with an unsupported one still parses to the one-line refusal.
MODELS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
          4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
          8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5),
          10: ("THIN_PRISM_FISHEYE", 12), 11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16)}
_PARAM_COUNTS = dict(MODELS.values())  # model name -> number of parameters
_IMAGE_FIELDS = 10  # IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME


def model_dir(path):
  """The folder under `path` holding a COLMAP model (MODEL_DIRS), or None."""
  for sub in MODEL_DIRS:
    folder = os.path.join(path, sub)
    if any(os.path.isfile(os.path.join(folder, f"cameras{ext}")) for ext in (".bin", ".txt")):
      return folder
  return None


class _Bytes:
  """A binary file read front to back; DataError naming the file when it ends too soon."""

  def __init__(self, path):
    self.path = path
    try:
      with open(path, "rb") as f:
        self.data = f.read()
    except OSError as e:
      raise DataError(f"{path}: cannot read ({e.strerror})") from None
    self.pos = 0

  def read(self, fmt):
    size = struct.calcsize("<" + fmt)
    if self.pos + size > len(self.data):
      raise DataError(f"{self.path}: ends at byte {len(self.data)} in the middle of a record "
                      "(truncated or not a COLMAP binary file)")
    values = struct.unpack_from("<" + fmt, self.data, self.pos)
    self.pos += size
    return values

  def skip(self, size):
    if self.pos + size > len(self.data):
      raise DataError(f"{self.path}: ends at byte {len(self.data)} in the middle of a record "
                      "(truncated or not a COLMAP binary file)")
    self.pos += size

  def array(self, dtype, count):
    """The next `count` records of numpy `dtype` (little-endian) as an array."""
    size = np.dtype(dtype).itemsize * count
    if self.pos + size > len(self.data):
      raise DataError(f"{self.path}: ends at byte {len(self.data)} in the middle of a record "
                      "(truncated or not a COLMAP binary file)")
    values = np.frombuffer(self.data, dtype, count, self.pos)
    self.pos += size
    return values

  def name(self):
    end = self.data.find(b"\0", self.pos)
    if end < 0:
      raise DataError(f"{self.path}: an image name has no terminating NUL byte (truncated?)")
    name, self.pos = self.data[self.pos:end].decode("utf-8", "replace"), end + 1
    return name

  def done(self):
    if self.pos != len(self.data):
      raise DataError(f"{self.path}: {len(self.data) - self.pos} bytes after the last record "
                      "(not a COLMAP binary file, or its count is wrong)")


def _text_rows(path):
  """(line number, words) of each line of a COLMAP text file that is not a comment; blank
  lines kept (an image's 2D points line can be empty)."""
  try:
    with open(path, encoding="utf-8") as f:
      lines = f.read().splitlines()
  except (OSError, UnicodeDecodeError) as e:
    raise DataError(f"{path}: cannot read ({getattr(e, 'strerror', None) or type(e).__name__})"
                    ) from None
  return [(n, line.split()) for n, line in enumerate(lines, 1) if not line.startswith("#")]


def read_cameras(path):
  """{camera id: (model name, width, height, float64 params [P])} of cameras.bin or .txt."""
  cameras = {}
  if path.endswith(".bin"):
    f = _Bytes(path)
    for _ in range(f.read("Q")[0]):
      camera_id, model_id, width, height = f.read("iiQQ")
      if model_id not in MODELS:
        raise DataError(f"{path}: camera {camera_id} has unknown model id {model_id} (not a "
                        "COLMAP camera model)")
      name, count = MODELS[model_id]
      cameras[camera_id] = (name, int(width), int(height), np.array(f.read(f"{count}d")))
    f.done()
    return cameras
  for n, words in _text_rows(path):
    if not words:
      continue
    try:
      camera_id, name, width, height = int(words[0]), words[1], int(words[2]), int(words[3])
      params = np.array([float(w) for w in words[4:]])
    except (ValueError, IndexError):
      raise DataError(f"{path}: line {n} is not 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]'"
                      ) from None
    if name in _PARAM_COUNTS and len(params) != _PARAM_COUNTS[name]:
      raise DataError(f"{path}: line {n}: {name} takes {_PARAM_COUNTS[name]} parameters, not "
                      f"{len(params)}")
    cameras[camera_id] = (name, width, height, params)
  return cameras


def read_images(path):
  """{image id: (float64 quaternion [4] (w, x, y, z), float64 translation [3], camera id,
  name)} of images.bin or .txt: world-to-camera, OpenCV axes."""
  return {image_id: record[:4] for image_id, record in _image_records(path).items()}


def read_keypoints(path):
  """{image id: (float64 [M, 2] (x, y) in pixels, int64 [M] point3D ids)} of images.bin or .txt:
  each image's 2D points and the 3D point each sees (-1 = none)."""
  return {image_id: record[4:] for image_id, record in _image_records(path).items()}


_POINT2D = np.dtype([("xy", "<f8", (2,)), ("id", "<i8")])  # a 2D point of images.bin


def _image_records(path):
  """{image id: (quaternion, translation, camera id, name, xy float64 [M, 2], point3D ids
  int64 [M])} of images.bin or .txt (`read_images`, `read_keypoints`)."""
  images = {}
  if path.endswith(".bin"):
    f = _Bytes(path)
    for _ in range(f.read("Q")[0]):
      image_id, *qt, camera_id = f.read("i7di")
      name = f.name()
      points = f.array(_POINT2D, f.read("Q")[0])
      images[image_id] = (np.array(qt[:4]), np.array(qt[4:]), camera_id, name,
                          points["xy"].astype(np.float64), points["id"].astype(np.int64))
    f.done()
    return images
  rows = _text_rows(path)
  while rows and not rows[-1][1]:  # blank lines at the end of the file
    rows.pop()
  for k in range(0, len(rows), 2):  # each image's line, then its 2D points' line
    n, words = rows[k]
    try:
      if len(words) < _IMAGE_FIELDS:
        raise ValueError
      image_id, values = int(words[0]), [float(w) for w in words[1:8]]
      camera_id, name = int(words[8]), " ".join(words[9:])
    except ValueError:
      raise DataError(f"{path}: line {n} is not 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'"
                      ) from None
    xy, ids = _points2d(path, *(rows[k + 1] if k + 1 < len(rows) else (n + 1, [])))
    images[image_id] = (np.array(values[:4]), np.array(values[4:]), camera_id, name, xy, ids)
  return images


def _points2d(path, n, words):
  """(xy float64 [M, 2], point3D ids int64 [M]) of line `n` of images.txt, its `words`
  (X Y POINT3D_ID triples)."""
  try:
    if len(words) % 3:
      raise ValueError
    xy = np.array([float(w) for w in words], np.float64).reshape(-1, 3)[:, :2]
    ids = np.array([int(w) for w in words[2::3]], np.int64)
  except ValueError:
    raise DataError(f"{path}: line {n} is not the 2D points 'X Y POINT3D_ID ...'") from None
  return xy, ids


def read_points(path):
  """(float64 [P, 3] positions, uint8 [P, 3] colours) of points3D.bin or .txt."""
  points = read_sparse_points(path)
  return points.xyz, points.rgb


@dataclasses.dataclass(frozen=True)
class SparsePoints:
  """points3D's records, in file order: P points, T track elements over them all.

  ids: int64 [P], POINT3D_ID. xyz: float64 [P, 3]. rgb: uint8 [P, 3]. errors: float64 [P], each
  point's mean reprojection error in pixels (COLMAP's ERROR). track_points: int64 [T], the index
  (into the P points) of each track element's point; track_images: int64 [T], its IMAGE_ID;
  track_points2d: int64 [T], its POINT2D_IDX (the 2D point of that image).
  """
  ids: np.ndarray
  xyz: np.ndarray
  rgb: np.ndarray
  errors: np.ndarray
  track_points: np.ndarray
  track_images: np.ndarray
  track_points2d: np.ndarray


_TRACK = np.dtype([("image", "<i4"), ("point2d", "<i4")])  # a track element of points3D.bin


def read_sparse_points(path):
  """SparsePoints of points3D.bin or .txt; DataError for a malformed line or record, or a
  position that is NaN or inf (an error that is, or is < 0, is unknown: kept as it is)."""
  ids, xyz, rgb, errors, tracks = [], [], [], [], []
  if path.endswith(".bin"):
    f = _Bytes(path)
    for _ in range(f.read("Q")[0]):
      values = f.read("Q3d3Bd")
      ids.append(values[0])
      xyz.append(values[1:4])
      rgb.append(values[4:7])
      errors.append(values[7])
      track = f.array(_TRACK, f.read("Q")[0])
      tracks.append(np.stack([track["image"], track["point2d"]], -1).astype(np.int64))
    f.done()
  else:
    for n, words in _text_rows(path):
      if not words:
        continue
      try:
        if len(words) < 8 or (len(words) - 8) % 2:
          raise ValueError
        ids.append(int(words[0]))
        xyz.append([float(w) for w in words[1:4]])
        rgb.append([int(w) for w in words[4:7]])
        errors.append(float(words[7]))
        tracks.append(np.array([int(w) for w in words[8:]], np.int64).reshape(-1, 2))
      except ValueError:
        raise DataError(f"{path}: line {n} is not 'POINT3D_ID X Y Z R G B ERROR TRACK[]'"
                        ) from None
  xyz = np.array(xyz, np.float64).reshape(-1, 3)
  if not np.all(np.isfinite(xyz)):
    raise DataError(f"{path}: point positions contain NaN or inf")
  errors = np.array(errors, np.float64)
  lengths = [len(t) for t in tracks]
  track = np.concatenate(tracks) if tracks else np.zeros((0, 2), np.int64)
  return SparsePoints(np.array(ids, np.int64), xyz, np.array(rgb, np.uint8).reshape(-1, 3),
                      errors, np.repeat(np.arange(len(lengths)), lengths).astype(np.int64),
                      track[:, 0], track[:, 1])


def observations(image_ids, points):
  """int32 [K, 2]: the (image index, point index) pairs of the tracks of `points`
  (SparsePoints) whose image is among `image_ids` (COLMAP image ids in the Dataset's order:
  image index k is image_ids[k]), each pair once, sorted by image then point. Track elements of
  other images (not loaded, or not registered) are left out."""
  image_ids = np.asarray(image_ids, np.int64).reshape(-1)
  if not len(image_ids):
    return np.zeros((0, 2), np.int32)
  order = np.argsort(image_ids, kind="stable")
  at = np.minimum(np.searchsorted(image_ids[order], points.track_images), len(order) - 1)
  kept = image_ids[order][at] == points.track_images
  pairs = np.stack([order[at][kept], points.track_points[kept]], -1)
  return np.unique(pairs.reshape(-1, 2), axis=0).astype(np.int32)


def model_files(folder):
  """The paths of the model's cameras, images and points3D files in `folder`: the three .bin
  files, else the three .txt files; DataError when neither set is complete."""
  for ext in (".bin", ".txt"):
    paths = [os.path.join(folder, name + ext) for name in FILES]
    if all(os.path.isfile(p) for p in paths):
      return paths
  raise DataError(f"{folder}: a COLMAP model needs {', '.join(FILES)} all .bin or all .txt "
                  f"(has: {', '.join(sorted(os.listdir(folder)))})")


def read_model(folder):
  """(cameras, images, (points, colours)) of the model in `folder` (`model_files`; read_cameras,
  read_images, read_points)."""
  cameras_file, images_file, points_file = model_files(folder)
  return read_cameras(cameras_file), read_images(images_file), read_points(points_file)


def rotation(quaternion):
  """float64 [3, 3] of a quaternion float [4] (w, x, y, z), normalised first."""
  w, x, y, z = np.asarray(quaternion, np.float64) / np.linalg.norm(quaternion)
  return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                   [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                   [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


FIT_TOLERANCE = 0.01  # a model beside other poses fits them to this (module `beside`)


def beside(path, poses, names=None, where=""):
  """The tracks of the COLMAP model under `path` (`model_dir`) for a loader whose own poses
  came from it (transforms.json, LLFF's poses_bounds.npy): (points float64 [P, 3] in the frame
  of `poses`, errors float64 [P], observations int32 [K, 2]), or None.

  poses: float [N, 4, 4], the loader's camera-to-world poses (OpenGL axes) of its N images, in
  the file's own frame (before the loader moves the world). names: each image's file name (a
  COLMAP image matches the name that ends with its NAME, path by path), or None: image k is the
  k-th of the model's images by name (LLFF's rule). The points are carried into the poses'
  frame by the similarity that takes the matched COLMAP cameras onto `poses` (`fit`). None,
  with one printed line naming `where`, when fewer than two images match or the cameras do not
  fit within FIT_TOLERANCE (another model); None without a model or without tracks.
  """
  folder = model_dir(path)
  if folder is None:
    return None
  try:  # the loader's poses come from its own file: a broken model only costs the tracks
    _, images_file, points_file = model_files(folder)
    images = read_images(images_file)
  except DataError as e:
    print(f"{where or path}: {e}; its tracks are not used", flush=True)
    return None
  ids = sorted(images, key=lambda i: images[i][3])
  if names is None:
    matched = ids if len(ids) == len(poses) else []
  else:
    by_name = {os.path.normpath(images[i][3]): i for i in ids}
    matched = [_match(name, by_name) for name in names]
  found = [k for k, image_id in enumerate(matched) if image_id is not None]
  say = lambda why: print(f"{where or path}: the COLMAP model in {folder} {why}; its tracks "
                          "are not used", flush=True)
  if names is None and not matched:
    say(f"has {len(ids)} images, not {len(poses)}")
    return None
  if len(found) < 2:
    say(f"matches {len(found)} of the {len(poses)} images")
    return None
  model = np.stack([_c2w(images[matched[k]]) for k in found])
  transform, misfit = fit(model, np.asarray(poses, np.float64)[found])
  if transform is None or misfit > FIT_TOLERANCE:
    say("does not fit the poses" if transform is None else
        f"fits the poses only to {misfit:.3g} (more than {FIT_TOLERANCE:g})")
    return None
  sparse = read_sparse_points(points_file)
  seen = observations([-1 if i is None else i for i in matched], sparse)
  if not len(seen):
    return None
  points = sparse.xyz @ transform[:3, :3].T + transform[:3, 3]
  return points, sparse.errors, seen


def _match(name, by_name):
  """The COLMAP image id of the file `name` (by_name: {normalised NAME: id}): the image whose
  NAME ends the path, path by path; None if none."""
  parts = os.path.normpath(name).split(os.sep)
  for start in range(len(parts)):
    image_id = by_name.get(os.path.join(*parts[start:]))
    if image_id is not None:
      return image_id
  return None


def _c2w(image):
  """float64 [4, 4] camera-to-world (OpenGL axes) of a `read_images` record."""
  quaternion, translation = image[0], image[1]
  return sfm.c2w_from_cam_from_world(
      np.concatenate([rotation(quaternion), translation[:, None]], axis=1))


def fit(source, target):
  """(transform float64 [4, 4], misfit float): the similarity x -> s R x + t that takes the
  camera-to-world poses `source` (float [M, 4, 4]) onto `target` (float [M, 4, 4]): R the
  rotation nearest every target_rot source_rot^T (the polar factor of their sum), s and t the
  least-squares fit of the centres under R. misfit: the larger of the worst centre's distance
  (a share of the target centres' RMS distance to their mean) and the worst camera's angle
  (radians). (None, inf) when the source centres coincide (no scale to fit) or fit only with a
  negative scale."""
  source, target = np.asarray(source, np.float64), np.asarray(target, np.float64)
  u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", target[:, :3, :3], source[:, :3, :3]))
  rot = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
  a, b = source[:, :3, 3], target[:, :3, 3]
  a0, b0 = a - a.mean(0), b - b.mean(0)
  spread = float(np.sum(a0 * a0))
  if not spread > 0:
    return None, np.inf
  scale = float(np.sum((a0 @ rot.T) * b0)) / spread
  if not scale > 0:  # the centres fit only mirrored: not the same cameras
    return None, np.inf
  transform = np.eye(4)
  transform[:3, :3], transform[:3, 3] = scale * rot, b.mean(0) - scale * rot @ a.mean(0)
  rms = max(float(np.sqrt(np.mean(np.sum(b0 * b0, -1)))), 1e-12)
  centres = np.linalg.norm(a @ transform[:3, :3].T + transform[:3, 3] - b, axis=-1).max() / rms
  turn = np.einsum("nji,jk,nkl->nil", target[:, :3, :3], rot, source[:, :3, :3])
  angles = np.arccos(np.clip((np.trace(turn, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
  return transform, max(float(centres), float(angles.max()))
