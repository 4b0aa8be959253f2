"""A COLMAP sparse model as it comes, the folder nerfstudio's colmap parser reads: DIR/images/
and DIR/sparse/0/ (or DIR/sparse/, DIR/colmap/sparse/0/) holding cameras, images and points3D,
all three binary (`.bin`) or all three text (`.txt`), read by colmap_model.py (COLMAP's
documented formats). The camera models read are `lens.COLMAP_PARAMS`' (SIMPLE_PINHOLE, PINHOLE,
SIMPLE_RADIAL, RADIAL, OPENCV); an image of another model is a DataError naming it.

`load` turns the model into a Dataset the way `nerfstudio.load` turns a transforms.json folder
nobody normalised into one: poses to camera-to-world with OpenGL axes
(`sfm.c2w_from_cam_from_world`); lens distortion removed at load
(`nerfstudio.undistort_frames`: one shared pinhole, or per-image cameras where the images'
COLMAP cameras differ); the scene re-oriented (z up) and scaled into [-1, 1]^3 from the points
(`orient`); near and far from the points' depths; `Dataset.points`, and `aabb` and `core` the
points' box; `Dataset.point_errors` and `Dataset.observations` from the points' errors and
tracks (`colmap_model.observations`). data.factor reads DIR/images_{factor}/ where it exists
(as LLFF's and nerfstudio's tools write it), else block-averages DIR/images/. Masks (optional):
DIR/masks/, one per image under the image's name (or with '.png'), white = keep
(`nerf_jax.data.masks`), min-pooled by data.factor and resampled with their images.
"""

import os

import numpy as np

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data import (lens, masks as masks_lib, nerfstudio, orient, resampling, sfm,
                           validate)
# FILES, MODEL_DIRS and model_dir are also read through this module (loaders.py, the tests).
from nerf_jax.data.colmap_model import (FILES, MODEL_DIRS, model_dir, model_files, observations,
                                        read_cameras, read_images, read_sparse_points, rotation)
from nerf_jax.data.data_settings import DataSettings
from nerf_jax.data.dataset import DataError, Dataset


def _image(path, name, factor):
  """float64 [H, W, 3|4]: image `name` from images_{factor}/, else images/ block-averaged by
  `factor`."""
  scaled = os.path.join(path, f"images_{factor}", name)
  if factor > 1 and os.path.isfile(scaled):
    return validate.read_image(scaled)
  full = os.path.join(path, "images", name)
  if not os.path.isfile(full):
    raise DataError(f"{full}: image {name!r} of the COLMAP model not found")
  return resampling.block_mean(validate.read_image(full), factor)


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


def load(path, background=(0.0, 0.0, 0.0), factor=DataSettings.factor):
  """The registered images of the COLMAP model under `path` (module docstring), sorted by name:
  (Dataset, names). factor: int >= 1, downscale the images by it."""
  folder = model_dir(path)
  if folder is None:
    raise DataError(f"{path}: no COLMAP model in {' or '.join(MODEL_DIRS)}")
  if int(factor) != factor or factor < 1:
    raise DataError(f"{path}: factor={factor} must be an integer >= 1")
  factor = int(factor)
  cameras_file, images_file, points_file = model_files(folder)
  cameras, images = read_cameras(cameras_file), read_images(images_file)
  sparse = read_sparse_points(points_file)
  points = sparse.xyz
  if not images:
    raise DataError(f"{images_file}: no registered images")
  frames, poses, lenses, names = [], [], [], []
  image_ids = sorted(images, key=lambda i: images[i][3])
  for quaternion, translation, camera_id, name in (images[i] for i in image_ids):
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
                        np.stack(masks) if len(set(sizes)) == 1 else masks),
                    **_tracks(image_ids, sparse))
  return dataset, names


def _tracks(image_ids, sparse):
  """Dataset's point_errors and observations of the model's points `sparse` (SparsePoints) seen
  by the images `image_ids` (in the Dataset's order), or {} without any such observation."""
  seen = observations(image_ids, sparse)
  if not len(seen):
    return {}
  return {"point_errors": sparse.errors.astype(np.float32), "observations": seen}


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


def load_split(path, background=(0.0, 0.0, 0.0), factor=DataSettings.factor,
               holdout_from=DataSettings.holdout_from):
  """(train, test) Datasets of `load`: test = every 8th image (0, 8, 16, ... by name: LLFF's
  convention, which nerfstudio's colmap parser follows in its 'interval' eval mode);
  holdout_from >= 1 holds out images [holdout_from:] instead (`Dataset.split`)."""
  dataset, _ = load(path, background, factor)
  return dataset.split_every(8) if holdout_from == -1 else dataset.split(holdout_from)
