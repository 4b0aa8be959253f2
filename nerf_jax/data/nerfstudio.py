"""The nerfstudio / instant-ngp `transforms.json` format: what `nerf-process` writes and what
nerfstudio's `ns-process-data` writes.

Fields read (top level for one camera, or per frame for several; a frame's own value wins):
  fl_x, fl_y (default fl_x), or camera_angle_x / camera_angle_y (instant-ngp);
  cx, cy (default the image centre), w, h (default the image size), all in pixels, COLMAP's
  convention (`nerf_jax.data.lens`); camera_model ('OPENCV' or absent: pinhole + k1, k2, k3,
  p1, p2; fisheye and equirectangular models are refused);
  frames[].file_path (relative to the folder), frames[].transform_matrix (camera-to-world,
  OpenGL axes, as `nerf_jax.cameras.rays`);
  frames[].sharpness (optional, instant-ngp's colmap2nerf: the variance of the Laplacian),
    read when `min_sharpness` > 0 (`sharp_frames`);
  train_filenames / test_filenames (optional split, nerfstudio's names);
  ply_file_path (optional sparse points, used to centre and scale, and for `Dataset.aabb`);
  a COLMAP model beside the file (colmap/sparse/0 as nerf-process and ns-process-data keep it,
    or sparse/0): its points' tracks (`Dataset.observations`), its images matched to the frames
    by file name, its points carried onto the frames' poses (`colmap_model.beside`);
  aabb_scale, scale, offset (optional, instant-ngp's scene box, `ngp_box`);
  near, far, nerf_jax_normalized (written by `nerf-process`).
  frames[].mask_path (optional, nerfstudio's masks: 0 = ignore the pixel), else instant-ngp's
    dynamic_mask_<image stem>.png beside the image (non-zero = dynamic: ignore); see
    `nerf_jax.data.masks`; a full-size mask is made smaller with its image (a min pool).
Ignored: applied_transform (nerfstudio's record of the rotation it already applied to the poses
and to the points of ply_file_path).

Frames whose image is missing are skipped, with one printed line, as instant-ngp does; more than
half missing is an error (the wrong folder or factor).

Lens distortion is removed once, at load: each image is resampled (bilinear) into a pinhole
camera, so the rest of the code sees plain (fx, fy, cx, cy). Frames of one camera (one size,
intrinsics within 1e-6 px, one distortion) share one pinhole, the mean of their intrinsics, as
`Dataset.intrinsics`; frames of several cameras keep their own intrinsics and size
(`Dataset.image_cameras`; images of different sizes are a list), each resampled only to remove
its own distortion. Frames without distortion whose intrinsics are their pinhole's are not
resampled. Folders that `nerf-process` did not normalise are re-oriented and scaled at load
(`nerf_jax.data.orient`).
"""

import json
import math
import os

import numpy as np

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data import (colmap_model, lens, masks as masks_lib, orient, pointcloud,
                           resampling, validate)
from nerf_jax.data.data_settings import DataSettings
from nerf_jax.data.dataset import DataError, Dataset
from nerf_jax.data.validate import composite, parse_background

FILENAME = "transforms.json"
_UNSUPPORTED_MODELS = ("OPENCV_FISHEYE", "EQUIRECTANGULAR", "FISHEYE")
_DIST_KEYS = ("k1", "k2", "p1", "p2", "k3")
SHARPNESS_WINDOW = 3  # neighbours on each side whose mean sharpness a frame is judged against
NGP_SCALE, NGP_OFFSET = 0.33, 0.5  # instant-ngp's default world -> ngp-space map (NERF_SCALE)
_LISTED = 5  # missing file names printed before "…"


def write(out_dir, frames, camera, extra, mask_paths=None):
  """Write OUT/transforms.json.

  frames: list of (file_path str, pose float [4, 4]). camera: dict of the shared camera's
  fl_x, fl_y, cx, cy, w, h, k1, k2, p1, p2 (top level), or a list of such dicts, one per frame.
  extra: dict of further top-level fields. mask_paths: None, or each frame's mask_path (str, or
  None for a frame without a mask).
  """
  shared = isinstance(camera, dict)
  mask_paths = [None] * len(frames) if mask_paths is None else mask_paths
  meta = {"camera_model": "OPENCV", **(camera if shared else {})}
  meta["frames"] = [{"file_path": path, "transform_matrix": np.asarray(pose).tolist(),
                     **({} if mask_paths[k] is None else {"mask_path": mask_paths[k]}),
                     **({} if shared else camera[k])} for k, (path, pose) in enumerate(frames)]
  meta.update(extra)
  with open(os.path.join(out_dir, FILENAME), "w") as f:
    json.dump(meta, f, indent=2)


def _number(frame, meta, key, where, default=None):
  value = frame.get(key, meta.get(key, default))
  if value is None:
    raise DataError(f"{where}: missing key {key!r} (per frame or at the top level)")
  return validate.scalar(value, f"{where}.{key}")


def _camera(frame, meta, image_size, full_size, where):
  """(COLMAP-convention (fx, fy, cx, cy), dist (k1, k2, p1, p2, k3)) of one frame, scaled to
  the image's actual size. image_size, full_size: (height, width) of the loaded image and of
  the photo before any downscaling (the default of w, h)."""
  model = frame.get("camera_model", meta.get("camera_model", "OPENCV"))
  if model in _UNSUPPORTED_MODELS:
    raise DataError(f"{where}.camera_model: {model!r} is not supported (OPENCV or a pinhole)")
  height, width = image_size
  w = _number(frame, meta, "w", where, full_size[1])
  h = _number(frame, meta, "h", where, full_size[0])
  if "fl_x" in frame or "fl_x" in meta:
    fx = _number(frame, meta, "fl_x", where)
  elif "camera_angle_x" in frame or "camera_angle_x" in meta:
    fx = 0.5 * w / math.tan(0.5 * _number(frame, meta, "camera_angle_x", where))
  else:
    raise DataError(f"{where}: missing key 'fl_x' (or 'camera_angle_x')")
  if "fl_y" in frame or "fl_y" in meta:
    fy = _number(frame, meta, "fl_y", where)
  elif "camera_angle_y" in frame or "camera_angle_y" in meta:
    fy = 0.5 * h / math.tan(0.5 * _number(frame, meta, "camera_angle_y", where))
  else:
    fy = fx
  cx, cy = _number(frame, meta, "cx", where, 0.5 * w), _number(frame, meta, "cy", where, 0.5 * h)
  sx, sy = width / w, height / h
  if abs(sx - sy) > 0.01 * sx:
    raise DataError(f"{where}: image is {width}x{height} but w, h say {w:g}x{h:g} (a different "
                    "aspect ratio)")
  if not (fx > 0 and fy > 0):
    raise DataError(f"{where}: focal lengths fl_x={fx:g}, fl_y={fy:g} must be positive")
  dist = tuple(_number(frame, meta, k, where, 0.0) for k in _DIST_KEYS)
  return (fx * sx, fy * sy, cx * sx, cy * sy), dist


def _scaled_path(root, file_path, factor):
  """Where nerfstudio keeps the frame downscaled by `factor`: images/a.png -> images_4/a.png."""
  parts = os.path.normpath(file_path).split(os.sep)
  if factor > 1 and len(parts) > 1:
    return os.path.join(root, f"{parts[0]}_{factor}", *parts[1:])
  return None


def _image_path(root, file_path, factor):
  """(path, prescaled) of the frame's image, from `images_{factor}/` when nerfstudio wrote
  downscaled copies; (None, False) when neither it nor the full image exists."""
  scaled = _scaled_path(root, file_path, factor)
  if scaled and os.path.isfile(scaled):
    return scaled, True
  path = os.path.join(root, file_path)
  return (path, False) if os.path.isfile(path) else (None, False)


def _folders(root, file_paths, factor):
  """The folders the images of `file_paths` were looked for in (images_{factor}/ where it
  exists), as one string for messages."""
  folders = []
  for file_path in file_paths:
    scaled = _scaled_path(root, file_path, factor)
    full = os.path.dirname(os.path.normpath(os.path.join(root, file_path)))
    for folder in [full] + ([os.path.dirname(scaled)] if scaled else []):
      if folder not in folders and (folder == full or os.path.isdir(folder)):
        folders.append(folder)
  return " or ".join(folders)


def _found_frames(root, meta_path, frames, factor):
  """The frames whose image exists, as (k, frame, image path, prescaled); prints which were
  skipped. frames: list of (k, frame dict) in file order."""
  found = [(k, frame, *_image_path(root, frame["file_path"], factor)) for k, frame in frames]
  missing = [frame["file_path"] for _, frame, path, _ in found if path is None]
  if not missing:
    return found
  folder = _folders(root, missing, factor)
  if len(missing) == len(frames):
    raise DataError(f"{meta_path}: none of the {len(frames)} frames' images is in {folder}")
  if 2 * len(missing) > len(frames):
    raise DataError(f"{meta_path}: {len(missing)} of {len(frames)} frames' images are missing "
                    f"from {folder} (the wrong folder or data.factor?)")
  names = [os.path.basename(p) for p in missing[:_LISTED]] + ["…"] * (len(missing) > _LISTED)
  print(f"{meta_path}: skipped {len(missing)} of {len(frames)} frames whose image is not in "
        f"{folder}: {', '.join(names)}", flush=True)
  return [f for f in found if f[2] is not None]


def sharp_frames(sharpness, min_sharpness):
  """Which frames are sharp enough: bool [N].

  sharpness: float64 [N], each frame's sharpness in file order (NaN: none given, kept).
  A rated frame is dropped when its sharpness < min_sharpness x the mean sharpness of the rated
  frames within SHARPNESS_WINDOW places of it (itself included; fewer at the ends).
  min_sharpness <= 0 keeps every frame.
  This is instant-ngp's rule (src/nerf_loader.cu, the file's `sharpness_discard_threshold`,
  kept when sharpness > threshold x mean) with a symmetric window: its window runs from 3 before
  to 2 after (the end of its loop stops one short); its frames with missing images count
  towards the mean, ours (skipped before) do not.
  """
  sharpness = np.asarray(sharpness, np.float64)
  keep = np.ones(len(sharpness), bool)
  if min_sharpness <= 0:
    return keep
  rated = np.flatnonzero(~np.isnan(sharpness))
  values = sharpness[rated]
  for j, k in enumerate(rated):
    window = values[max(0, j - SHARPNESS_WINDOW):j + SHARPNESS_WINDOW + 1]
    keep[k] = values[j] >= min_sharpness * window.mean()
  return keep


def _drop_blurry(found, min_sharpness, meta_path):
  """`found` (see `_found_frames`) less the frames `sharp_frames` drops; prints how many."""
  if min_sharpness <= 0 or not any("sharpness" in frame for _, frame, _, _ in found):
    return found
  sharpness = [validate.scalar(frame["sharpness"], f"{meta_path}: frames[{k}].sharpness")
               if "sharpness" in frame else np.nan for k, frame, _, _ in found]
  keep = sharp_frames(sharpness, min_sharpness)
  if not keep.any():
    raise DataError(f"{meta_path}: min_sharpness={min_sharpness:g} drops all {len(keep)} frames")
  print(f"{meta_path}: dropped {int((~keep).sum())} of {len(keep)} frames less sharp than "
        f"{min_sharpness:g}x their neighbours' mean sharpness", flush=True)
  return [f for f, kept in zip(found, keep) if kept]


def ngp_box(meta, meta_path, unit=False):
  """The scene box instant-ngp's `aabb_scale` gives, in the file's world coordinates: float64
  [2, 3] (min and max corner), or None without aabb_scale. unit: the box of aabb_scale 1
  instead, instant-ngp's unit cube (where its captures are sized to put the subject).

  instant-ngp (src/nerf_loader.cu, nerf_matrix_to_ngp) maps a world point x to ngp space as
  x * scale + offset (then cycles the axes; defaults scale 0.33, offset (0.5, 0.5, 0.5), the
  file's "scale" and "offset" override them); src/testbed_nerf.cu makes the box
  [0.5 - k/2, 0.5 + k/2]^3 there, k = aabb_scale (a cube: the axis cycle does not change it).
  Its "aabb" and "from_mitsuba" fields are not read.
  """
  if meta.get("aabb_scale") is None:
    return None
  k = validate.scalar(meta["aabb_scale"], f"{meta_path}: 'aabb_scale'")
  scale = validate.scalar(meta.get("scale", NGP_SCALE), f"{meta_path}: 'scale'")
  offset = validate.floats(meta.get("offset", NGP_OFFSET), f"{meta_path}: 'offset'")
  if not (k > 0 and scale > 0):
    raise DataError(f"{meta_path}: aabb_scale={k:g} and scale={scale:g} must be positive")
  if offset.shape not in ((), (3,)) or not np.isfinite(offset).all():
    raise DataError(f"{meta_path}: 'offset' must be one number or three, got {offset.tolist()}")
  k = 1.0 if unit else k
  corners = np.array([[0.5 - 0.5 * k], [0.5 + 0.5 * k]])
  return (corners - np.broadcast_to(offset, (3,))) / scale


def load(path, background=(0.0, 0.0, 0.0), factor=DataSettings.factor,
         min_sharpness=DataSettings.min_sharpness):
  """All frames of a transforms.json folder (or the file itself) whose image exists, sorted by
  file_path.

  factor: int, downscale the images by this factor (nerfstudio's `images_{factor}/` copies when
  present, else a block average). min_sharpness: float, drop blurry frames (`sharp_frames`;
  0 = keep all). Returns (Dataset, names, test_names): names, the frames' file_path values in
  the Dataset's order; test_names, the set of them the file names as test (or val) images, or
  None. Dataset.aabb: `ngp_box` where the file has aabb_scale, else `orient.points_box` of
  ply_file_path's points, else None; Dataset.core: instant-ngp's unit cube where the file has
  aabb_scale, else the points' box; both carried with the poses into the Dataset's frame, as
  are Dataset.points (ply_file_path's, or None). With a COLMAP model beside the file (`_tracks`:
  nerf-process's colmap/sparse/0), Dataset.points, point_errors and observations are its points
  and tracks, its images matched to the frames by file name.
  """
  meta_path = path if path.endswith(".json") else os.path.join(path, FILENAME)
  root = os.path.dirname(meta_path)
  meta = validate.read_json(meta_path)
  factor = int(factor) if factor else 1
  order = sorted(range(len(meta["frames"])), key=lambda k: str(meta["frames"][k].get("file_path")))
  for k in order:
    frame, where = meta["frames"][k], f"{meta_path}: frames[{k}]"
    if not isinstance(frame, dict) or "file_path" not in frame:
      raise DataError(f"{where}: missing key 'file_path'")
    if "transform_matrix" not in frame:
      raise DataError(f"{where}: missing key 'transform_matrix'")
  found = _found_frames(root, meta_path, [(k, meta["frames"][k]) for k in order], factor)
  found = _drop_blurry(found, min_sharpness, meta_path)
  images, poses, cameras, names, masks = [], [], [], [], []
  for k, frame, image_path, prescaled in found:
    where = f"{meta_path}: frames[{k}]"
    image = validate.read_image(image_path)
    full_size = tuple(n * (factor if prescaled else 1) for n in image.shape[:2])
    image = image if prescaled else resampling.block_mean(image, factor)
    masks.append(_mask(root, frame, factor, full_size, image.shape, where))
    poses.append(validate.poses(np.asarray(frame["transform_matrix"], np.float64)[None],
                                f"{where}.transform_matrix")[0])
    cameras.append(_camera(frame, meta, image.shape[:2], full_size, where))
    images.append(image.astype(np.float32))  # float64 for all frames would be 2x the memory
    names.append(frame["file_path"])
  images, intrinsics, masks = undistort_frames(images, cameras, masks)
  poses = np.stack(poses)
  near, far = meta.get("near"), meta.get("far")
  points, transform = _points(root, meta, meta_path), np.eye(4)
  tracks = _tracks(root, poses, names, meta_path)
  if not meta.get("nerf_jax_normalized", False):
    transform = orient.normalize(poses, points)
    poses, points = orient.apply(transform, poses, points)
    near, far = orient.depth_bounds(poses, points)
  near = validate.scalar(near if near is not None else 2.0, f"{meta_path}: 'near'")
  far = validate.scalar(far if far is not None else 6.0, f"{meta_path}: 'far'")
  box, unit = ngp_box(meta, meta_path), ngp_box(meta, meta_path, unit=True)
  aabb = orient.points_box(points) if box is None else orient.carry_box(transform, box)
  core = orient.points_box(points) if unit is None else orient.carry_box(transform, unit)
  bg = parse_background(background)
  sizes = [im.shape[:2] for im in images]
  one_size = len(set(sizes)) == 1
  rgb, accs = composite_frames(images, bg)
  own = None if isinstance(intrinsics, tuple) else Cameras.stack(
      [(*size, lens.dataset_intrinsics(k)) for size, k in zip(sizes, intrinsics)])
  dataset = Dataset(rgb, poses.astype(np.float32),
                    lens.dataset_intrinsics(intrinsics if own is None else intrinsics[0]),
                    near=near, far=far, name=root, image_cameras=own,
                    accs=accs,
                    background=tuple(bg.tolist()),
                    pixel_center=0.0,  # the intrinsics hold cx - 0.5: rays through centres
                    aabb=None if aabb is None else aabb.astype(np.float32),
                    core=None if core is None else core.astype(np.float32),
                    masks=_stack_masks(masks, sizes, one_size),
                    **_tracked(points, tracks, transform))
  return dataset, names, _test_names(meta, names)


def _tracks(root, poses, names, meta_path):
  """colmap_model.beside's tracks of a COLMAP model under `root` (nerf-process's
  colmap/sparse/0, ns-process-data's likewise) for the frames `names` at `poses` (the file's
  frame), or None."""
  return colmap_model.beside(root, poses, names, meta_path)


def _tracked(points, tracks, transform):
  """Dataset's points: `points` (ply_file_path's float [P, 3] in the Dataset's frame, or None)
  without `tracks` (colmap_model.beside's, or None); with them the model's points carried by
  `transform` (float64 [4, 4], the loader's move of the world) in their place (nerf-process
  writes the same points to the ply; the boxes, near and far stay the ply's), and its
  point_errors and observations."""
  if tracks is None:
    return {"points": None if points is None else points.astype(np.float32)}
  tracked, errors, seen = tracks
  return {"points": orient.apply(transform, None, tracked)[1].astype(np.float32),
          "point_errors": errors.astype(np.float32), "observations": seen}


def composite_frames(images, background):
  """(rgb, accs) of the frames `images` (a list of float [H_i, W_i, 3 or 4], emptied as it is
  read: no stacked float64 copy of them all) composited on `background` (float64 [3]): rgb
  float32 [N, H, W, 3] when the frames have one size, else a list of [H_i, W_i, 3]; accs the
  frames' alpha likewise ([N, H, W] or a list, 1 for RGB frames), None when no frame has alpha
  (RGB: the opacity is unknown)."""
  has_alpha = any(im.shape[-1] == 4 for im in images)
  sizes = [im.shape[:2] for im in images]
  one_size = len(set(sizes)) == 1
  rgb = np.empty((len(images), *sizes[0], 3), np.float32) if one_size else [None] * len(images)
  accs = np.ones(rgb.shape[:-1], np.float32) if one_size else [np.ones(n, np.float32)
                                                                for n in sizes]
  for k, image in enumerate(images):
    rgb[k] = composite(image, background)
    if image.shape[-1] == 4:
      accs[k] = image[..., 3]
    images[k] = None
  return rgb, accs if has_alpha else None


def _mask(root, frame, factor, full_size, image_shape, where):
  """The frame's mask (masks module docstring) as float32 [H, W] at its image's size, or None:
  frames[].mask_path (its images_{factor}/ copy where nerfstudio wrote one), else instant-ngp's
  dynamic_mask_<stem>.png. A mask of the full photo's size is min-pooled by `factor`."""
  if frame.get("mask_path"):
    path, _ = _image_path(root, frame["mask_path"], factor)
    if path is None:
      raise DataError(f"{where}.mask_path: mask {os.path.join(root, frame['mask_path'])} "
                      "not found")
    mask = masks_lib.read(path, "nonzero", f"{where}.mask_path")
  else:
    path = masks_lib.dynamic_mask_path(os.path.join(root, frame["file_path"]))
    if path is None:
      return None
    mask = masks_lib.read(path, "dynamic", path)
  if mask.shape == tuple(full_size) and factor > 1:
    mask = masks_lib.downscale(mask, factor)
  return masks_lib.check(mask, image_shape, f"{where}: {path}")


def _stack_masks(masks, sizes, one_size):
  """Dataset.masks of the frames' masks (None entries: keep every pixel): None when no frame has
  one, else float32 [N, H, W] (one size) or a list."""
  if all(m is None for m in masks):
    return None
  masks = [np.ones(size, np.float32) if m is None else m for m, size in zip(masks, sizes)]
  return np.stack(masks) if one_size else masks


def _points(root, meta, meta_path):
  """The sparse points (float64 [P, 3]) named by ply_file_path, or None."""
  if not meta.get("ply_file_path"):
    return None
  ply = os.path.join(root, meta["ply_file_path"])
  if not os.path.isfile(ply):
    raise DataError(f"{meta_path}: ply_file_path {ply} not found")
  return pointcloud.read_ply(ply)[0]


def undistort_frames(images, cameras, masks):
  """Images with their lens distortion removed (module docstring): (list of float32 [H_i, W_i,
  C], COLMAP-convention intrinsics, masks): one (fx, fy, cx, cy) tuple, the shared pinhole, for
  frames of one camera; a list of each frame's own for frames of several. masks: each frame's
  float32 [H_i, W_i] or None, resampled with its image (`masks.resample`)."""
  mean = tuple(float(v) for v in np.mean([c[0] for c in cameras], axis=0))
  one = (len({im.shape[:2] for im in images}) == 1 and len({c[1] for c in cameras}) == 1 and
         all(np.allclose(c[0], mean, rtol=0, atol=1e-6) for c in cameras))
  targets = [mean if one else tuple(float(v) for v in c[0]) for c in cameras]
  out, out_masks = [], []
  for image, (intrinsics, dist), target, mask in zip(images, cameras, targets, masks):
    exact = not any(dist) and np.allclose(intrinsics, target, rtol=0, atol=1e-6)
    out.append(image if exact else lens.resample(image, intrinsics, dist, target,
                                                 image.shape[:2]).astype(np.float32))
    out_masks.append(mask if exact or mask is None else masks_lib.resample(
        mask, intrinsics, dist, target, image.shape[:2]))
  return out, (mean if one else targets), out_masks


def _test_names(meta, names):
  """file_path values of the test split the file names (test, else val), or None."""
  for key in ("test_filenames", "val_filenames"):
    if meta.get(key):
      listed = {os.path.normpath(p) for p in meta[key]}
      return {n for n in names if os.path.normpath(n) in listed}
  return None


def load_split(path, background=(0.0, 0.0, 0.0), factor=DataSettings.factor,
               holdout_from=DataSettings.holdout_from, min_sharpness=DataSettings.min_sharpness):
  """(train, test) Datasets of `load`: the file's test_filenames, else every 8th frame (0, 8,
  16, ... of the sorted file paths); holdout_from >= 1 overrides both (`Dataset.split`)."""
  dataset, names, test_names = load(path, background, factor, min_sharpness)
  if holdout_from != -1:
    return dataset.split(holdout_from)
  if test_names is None:
    return dataset.split_every(8)
  is_test = np.array([n in test_names for n in names])
  if is_test.all() or not is_test.any():
    raise DataError(f"{path}: test_filenames leave an empty train or test split")
  return dataset.subset(np.flatnonzero(~is_test)), dataset.subset(np.flatnonzero(is_test))

