"""A COLMAP sparse model as it comes, the folder nerfstudio's colmap parser reads: DIR/images/
and DIR/sparse/0/ (or DIR/sparse/, DIR/colmap/sparse/0/) holding cameras, images and points3D,
all three binary (`.bin`) or all three text (`.txt`), in COLMAP's documented formats
(https://colmap.github.io/format.html). Pure numpy: pycolmap is not needed to read them.

cameras: CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[] (binary: int32 id, int32 model id, uint64
  width, uint64 height, float64 params). The models read are `lens.COLMAP_PARAMS`'
  (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV); an image of another model is a
  DataError naming it.
images: IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME, then the 2D points (not read):
  the rotation (a unit quaternion) and translation of world-to-camera with OpenCV axes (x right,
  y down, z forward); NAME is the file under DIR/images/.
points3D: POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] (binary: uint64 id, 3 float64, 3 uint8,
  float64 error, uint64 track length, then (int32, int32) pairs): the sparse points.

`load` turns the model into a Dataset the way `nerfstudio.load` turns a transforms.json folder
nobody normalised into one: poses to camera-to-world with OpenGL axes
(`sfm.c2w_from_cam_from_world`); lens distortion removed at load
(`nerfstudio.undistort_frames`: one shared pinhole, or per-image cameras where the images'
COLMAP cameras differ); the scene re-oriented (z up) and scaled into [-1, 1]^3 from the points
(`orient`); near and far from the points' depths; `Dataset.points`, and `aabb` and `core` the
points' box. data.factor reads DIR/images_{factor}/ where it exists (as LLFF's and
nerfstudio's tools write it), else block-averages DIR/images/. Masks (optional): DIR/masks/,
one per image under the image's name (or with '.png'), white = keep (`nerf_jax.data.masks`),
min-pooled by data.factor and resampled with their images.
"""

import os
import struct

import numpy as np

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data import lens, masks as masks_lib, nerfstudio, orient, sfm, validate
from nerf_jax.data.dataset import DataError, Dataset

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
  images = {}
  if path.endswith(".bin"):
    f = _Bytes(path)
    for _ in range(f.read("Q")[0]):
      image_id, *qt, camera_id = f.read("i7di")
      name = f.name()
      f.skip(24 * f.read("Q")[0])  # the 2D points: x, y float64, point3D id int64
      images[image_id] = (np.array(qt[:4]), np.array(qt[4:]), camera_id, name)
    f.done()
    return images
  rows = _text_rows(path)
  while rows and not rows[-1][1]:  # blank lines at the end of the file
    rows.pop()
  for (n, words) in rows[::2]:  # each image's line, then its 2D points' line
    try:
      if len(words) < _IMAGE_FIELDS:
        raise ValueError
      image_id, values = int(words[0]), [float(w) for w in words[1:8]]
      camera_id, name = int(words[8]), " ".join(words[9:])
    except ValueError:
      raise DataError(f"{path}: line {n} is not 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'"
                      ) from None
    images[image_id] = (np.array(values[:4]), np.array(values[4:]), camera_id, name)
  return images


def read_points(path):
  """(float64 [P, 3] positions, uint8 [P, 3] colours) of points3D.bin or .txt."""
  xyz, rgb = [], []
  if path.endswith(".bin"):
    f = _Bytes(path)
    for _ in range(f.read("Q")[0]):
      values = f.read("Q3d3Bd")
      xyz.append(values[1:4])
      rgb.append(values[4:7])
      f.skip(8 * f.read("Q")[0])  # the track: (image id, point2D index) int32 pairs
    f.done()
  else:
    for n, words in _text_rows(path):
      if not words:
        continue
      try:
        if (len(words) - 8) % 2:
          raise ValueError
        xyz.append([float(w) for w in words[1:4]])
        rgb.append([int(w) for w in words[4:7]])
        float(words[7])
      except (ValueError, IndexError):
        raise DataError(f"{path}: line {n} is not 'POINT3D_ID X Y Z R G B ERROR TRACK[]'"
                        ) from None
  xyz = np.array(xyz, np.float64).reshape(-1, 3)
  if not np.all(np.isfinite(xyz)):
    raise DataError(f"{path}: point positions contain NaN or inf")
  return xyz, np.array(rgb, np.uint8).reshape(-1, 3)


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


def _image(path, name, factor):
  """float64 [H, W, 3|4]: image `name` from images_{factor}/, else images/ block-averaged by
  `factor`."""
  scaled = os.path.join(path, f"images_{factor}", name)
  if factor > 1 and os.path.isfile(scaled):
    return validate.read_image(scaled)
  full = os.path.join(path, "images", name)
  if not os.path.isfile(full):
    raise DataError(f"{full}: image {name!r} of the COLMAP model not found")
  return nerfstudio.downscale(validate.read_image(full), factor)


def _camera(camera, camera_id, image_size, where):
  """(COLMAP-convention (fx, fy, cx, cy), dist (k1, k2, p1, p2)) of `camera` (read_cameras'
  tuple) scaled to the image's (height, width)."""
  model, width, height, params = camera
  if model not in lens.COLMAP_PARAMS:
    raise DataError(f"{where}: camera {camera_id} has model {model}, which is not supported "
                    f"(supported: {', '.join(lens.COLMAP_PARAMS)})")
  if len(params) != len(lens.COLMAP_PARAMS[model]):
    raise DataError(f"{where}: camera {camera_id} ({model}) has {len(params)} parameters, not "
                    f"{len(lens.COLMAP_PARAMS[model])}")
  (fx, fy, cx, cy), dist = lens.from_colmap(model, params)
  sx, sy = image_size[1] / width, image_size[0] / height
  if abs(sx - sy) > 0.01 * sx:
    raise DataError(f"{where}: camera {camera_id} is {width}x{height} but its image is "
                    f"{image_size[1]}x{image_size[0]} (a different aspect ratio)")
  if not (fx > 0 and fy > 0):
    raise DataError(f"{where}: camera {camera_id} has focal lengths {fx:g}, {fy:g}; they must "
                    "be positive")
  return (fx * sx, fy * sy, cx * sx, cy * sy), dist


def load(path, background=(0.0, 0.0, 0.0), factor=1):
  """The registered images of the COLMAP model under `path` (module docstring), sorted by name:
  (Dataset, names). factor: int >= 1, downscale the images by it."""
  folder = model_dir(path)
  if folder is None:
    raise DataError(f"{path}: no COLMAP model in {' or '.join(MODEL_DIRS)}")
  if int(factor) != factor or factor < 1:
    raise DataError(f"{path}: factor={factor} must be an integer >= 1")
  factor = int(factor)
  cameras, images, (points, _) = read_model(folder)
  cameras_file, images_file, _ = model_files(folder)
  if not images:
    raise DataError(f"{images_file}: no registered images")
  frames, poses, lenses, names = [], [], [], []
  for quaternion, translation, camera_id, name in sorted(images.values(), key=lambda v: v[3]):
    if camera_id not in cameras:
      raise DataError(f"{images_file}: image {name!r} has camera {camera_id}, which "
                      f"{cameras_file} does not list")
    if not np.all(np.isfinite(quaternion)) or not np.linalg.norm(quaternion) > 0:
      raise DataError(f"{images_file}: image {name!r} has no valid rotation {quaternion}")
    image = _image(path, name, factor)
    lenses.append(_camera(cameras[camera_id], camera_id, image.shape[:2], cameras_file))
    w2c = np.concatenate([rotation(quaternion), translation[:, None]], axis=1)
    poses.append(sfm.c2w_from_cam_from_world(w2c))
    frames.append(image.astype(np.float32))  # float64 for all frames would be 2x the memory
    names.append(name)
  masks = _masks(path, names, [f.shape for f in frames], factor)
  frames, intrinsics, masks = nerfstudio.undistort_frames(frames, lenses, masks)
  points = points if len(points) else None
  transform = orient.normalize(np.stack(poses), points)
  poses, points = orient.apply(transform, np.stack(poses), points)
  near, far = orient.depth_bounds(poses, points)
  box = orient.points_box(points)
  sizes = [im.shape[:2] for im in frames]
  bg = validate.parse_background(background)
  rgb, accs = nerfstudio.composite_frames(frames, bg)
  own = None if isinstance(intrinsics, tuple) else Cameras.stack(
      [(*size, lens.dataset_intrinsics(k)) for size, k in zip(sizes, intrinsics)])
  dataset = Dataset(rgb, poses.astype(np.float32),
                    lens.dataset_intrinsics(intrinsics if own is None else intrinsics[0]),
                    near=near, far=far, name=path, image_cameras=own, accs=accs,
                    background=tuple(bg.tolist()),
                    pixel_center=0.0,  # the intrinsics hold cx - 0.5: rays through centres
                    aabb=None if box is None else box.astype(np.float32),
                    core=None if box is None else box.astype(np.float32),
                    points=None if points is None else points.astype(np.float32),
                    masks=None if masks[0] is None else (
                        np.stack(masks) if len(set(sizes)) == 1 else masks))
  return dataset, names


def _masks(path, names, shapes, factor):
  """Each image's mask from DIR/masks/ (`masks.folder_masks`: the image's name, white = keep),
  float32 [H_i, W_i] at its image's shape (`shapes`; a full-size mask min-pooled by `factor`),
  or a list of None without masks/."""
  masks = masks_lib.folder_masks(path, names)
  if masks is None:
    return [None] * len(names)
  out = []
  for name, mask, shape in zip(names, masks, shapes):
    scaled = mask if mask.shape == shape[:2] else masks_lib.downscale(mask, factor)
    out.append(masks_lib.check(scaled, shape, os.path.join(path, masks_lib.MASKS_DIR, name)))
  return out


def load_split(path, background=(0.0, 0.0, 0.0), factor=1, holdout_from=-1):
  """(train, test) Datasets of `load`: test = every 8th image (0, 8, 16, ... by name: LLFF's
  convention, which nerfstudio's colmap parser follows in its 'interval' eval mode);
  holdout_from >= 1 holds out images [holdout_from:] instead (`Dataset.split`)."""
  dataset, _ = load(path, background, factor)
  return dataset.split_every(8) if holdout_from == -1 else dataset.split(holdout_from)
