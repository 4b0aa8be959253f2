"""The LLFF format of forward-facing captures: `poses_bounds.npy` and an `images/` folder.

poses_bounds.npy: float [N, 17]. Row k is the 3 x 5 matrix [R | t | hwf] of view k, flattened
row-major, then the near and far depth bounds of what view k sees:
  R — the camera's axes in world space as columns, in LLFF's order [down, right, backwards];
  t — the camera centre; hwf — (height, width, focal) in pixels of the images in `images/`.
NeRF's order (`nerf_jax.cameras.rays`) is [right, up, backwards], so on the column axis
  nerf = [llff_1, -llff_0, llff_2]      and back      llff = [-nerf_1, nerf_0, nerf_2].
images/: one image per view, matched to the rows in the order of their sorted file names.
images_{factor}/: the same downsampled by `factor`, as LLFF's tools write them.
sparse/0/ (optional; LLFF's archives hold it): the COLMAP model the poses came from; its points
  and their tracks become Dataset.points, point_errors and observations (`colmap_model.beside`: image
  k is images/' k-th name, or the model's k-th image by name; the points carried onto the poses
  and moved with them by recenter and bd_factor).
masks/ (optional): one mask per image, the same file name (or with '.png' added or in place of
  its extension), white = keep (`nerf_jax.data.masks`); a full-size mask is min-pooled by
  `factor` to its image's size.
"""

import os

import imageio.v3 as iio
import numpy as np

from nerf_jax.data import colmap_model, masks as masks_lib, resampling, validate
from nerf_jax.data.data_settings import DataSettings
from nerf_jax.data.dataset import DataError, Dataset

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def export_llff(dataset, dirpath):
  """Write `poses_bounds.npy` (each view with its bounds, dataset.bounds, else dataset.near,
  dataset.far) and `images/000.png`, ... (8-bit RGB) under `dirpath`, and `masks/000.png`, ...
  where the dataset has masks; DataError unless a centred pinhole."""
  focal = dataset.pinhole_focal()
  c2w = dataset.poses[:, :3, :4].astype(np.float64)
  num = len(dataset)
  hwf = np.broadcast_to([[dataset.height], [dataset.width], [focal]], (num, 3, 1))
  llff = np.concatenate([-c2w[:, :, 1:2], c2w[:, :, 0:1], c2w[:, :, 2:4], hwf], axis=2)
  bounds = (np.broadcast_to([dataset.near, dataset.far], (num, 2)) if dataset.bounds is None
            else np.asarray(dataset.bounds, np.float64))
  os.makedirs(os.path.join(dirpath, "images"), exist_ok=True)
  np.save(os.path.join(dirpath, "poses_bounds.npy"),
          np.concatenate([llff.reshape(num, 15), bounds], axis=1))
  digits = max(3, len(str(num - 1)))  # equal-length names sort in view order
  for k, image in enumerate(dataset.images):
    iio.imwrite(os.path.join(dirpath, "images", f"{k:0{digits}d}.png"),
                np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8))
    if dataset.masks is not None:
      masks_lib.write(os.path.join(dirpath, masks_lib.MASKS_DIR, f"{k:0{digits}d}.png"),
                      dataset.mask(k))


def _read_images(path, num_views, factor):
  """(float32 [N, H, W, 3] from `images_{factor}/`, or `images/` block-averaged by `factor`;
  the masks float32 [N, H, W] from masks/, or None)."""
  folder = os.path.join(path, f"images_{factor}")
  reduce = factor > 1 and not os.path.isdir(folder)
  if factor == 1 or reduce:
    folder = os.path.join(path, "images")
  if not os.path.isdir(folder):
    raise DataError(f"{path}: no images folder {os.path.basename(folder)}/")
  names = sorted(n for n in os.listdir(folder) if n.lower().endswith(_IMAGE_SUFFIXES))
  if len(names) != num_views:
    raise DataError(f"{folder}: {len(names)} images but poses_bounds.npy has {num_views} views")
  images = [validate.composite(validate.read_image(os.path.join(folder, n)), np.zeros(3))
            for n in names]  # any RGBA on black: LLFF captures are opaque photographs
  shapes = {im.shape[:2] for im in images}
  if len(shapes) > 1:
    raise DataError(f"{folder}: images have different sizes {sorted(shapes)}")
  images = resampling.block_mean(np.stack(images), factor if reduce else 1)
  return images, _read_masks(path, names, images.shape[1:3], factor)


def _read_masks(path, names, size, factor):
  """float32 [N, H, W] of masks/ beside images/ (module docstring) at the images' `size`, or
  None without masks/; DataError naming a missing, wrong-sized or all-ignoring mask."""
  masks = masks_lib.folder_masks(path, names)
  if masks is None:
    return None
  out = []
  for name, mask in zip(names, masks):
    scaled = mask if mask.shape == tuple(size) else masks_lib.downscale(mask, factor)
    out.append(masks_lib.check(scaled if scaled.shape == tuple(size) else mask, size,
                               os.path.join(path, masks_lib.MASKS_DIR, name)))
  return np.stack(out)


def _average_camera(c2w):
  """(frame float64 [3, 3], its axes as columns; centre float64 [3]) of the average camera of
  float64 [N, 3, 4] camera-to-world poses: at the mean centre, looking along the mean viewing
  direction, keeping the mean up vector (made orthogonal)."""
  backwards = np.sum(c2w[:, :, 2], 0)
  backwards /= np.linalg.norm(backwards)
  right = np.cross(np.sum(c2w[:, :, 1], 0), backwards)
  right /= np.linalg.norm(right)
  return np.stack([right, np.cross(backwards, right), backwards], axis=1), c2w[:, :, 3].mean(0)


def _recenter(c2w):
  """Express float64 [N, 3, 4] camera-to-world poses in the frame of their average camera
  (`_average_camera`); after this, NDC's world -z is the mean viewing direction."""
  frame, centre = _average_camera(c2w)
  rotations = np.einsum("ji,njk->nik", frame, c2w[:, :, :3])  # frame^T R
  centres = (c2w[:, :, 3] - centre) @ frame  # frame^T (t - centre), as rows
  return np.concatenate([rotations, centres[:, :, None]], axis=2)


def load_llff(path, factor=DataSettings.factor, bd_factor=None, recenter=False):
  """An LLFF folder (see the module docstring) as a forward-facing Dataset.

  factor: int >= 1, load `images_{factor}/` (or `images/` block-averaged by `factor`); the focal
    length scales with the image width.
  bd_factor: float or None. None keeps the file's units. A float (the original NeRF: 0.75)
    rescales the scene by 1 / (bd_factor * min near bound), so the nearest bound becomes
    1 / bd_factor > 1 and NDC's near plane z = -1 lies in front of all content.
  recenter: bool, express the poses in the frame of the average camera (`_recenter`), which NDC
    needs when the capture's world frame is arbitrary (e.g. COLMAP's).
  near, far: the smallest near bound and the largest far bound over all views; bounds: each
  view's own (Dataset.bounds, float32 [N, 2]). Returns a Dataset with accs = None, background = (0, 0, 0) (unknown) and forward_facing = True.
  """
  table_path = os.path.join(path, "poses_bounds.npy")
  if not os.path.isfile(table_path):
    raise DataError(f"{table_path}: no such file")
  try:
    table = np.load(table_path)
  except (OSError, ValueError) as e:
    raise DataError(f"{table_path}: not a readable .npy array ({type(e).__name__})") from None
  table = validate.floats(table, table_path)
  if table.ndim != 2 or table.shape[1] != 17 or not len(table):
    raise DataError(f"{table_path}: shape {table.shape}; expected [N, 17] (a 3 x 5 pose and "
                    "near, far bounds per view)")
  if not np.all(np.isfinite(table)):
    raise DataError(f"{table_path}: contains NaN or inf")
  matrices, bounds = table[:, :15].reshape(-1, 3, 5), table[:, 15:]
  if not np.all((bounds[:, 0] > 0) & (bounds[:, 1] > bounds[:, 0])):
    raise DataError(f"{table_path}: bounds must satisfy 0 < near < far in every row")
  hwf = matrices[:, :, 4]
  if np.any(hwf != hwf[0]) or np.any(hwf[0] <= 0):
    raise DataError(f"{table_path}: views must share one positive (height, width, focal)")
  if int(factor) != factor or factor < 1:
    raise DataError(f"{path}: factor={factor} must be an integer >= 1")

  images, masks = _read_images(path, len(table), int(factor))
  height, width = images.shape[1:3]
  scale = width / hwf[0, 1]  # images_{factor} may round, so take the scale from the width
  if abs(height - scale * hwf[0, 0]) > 1.0:
    raise DataError(f"{path}: images are {height} x {width}, not a scaling of poses_bounds.npy's "
                    f"{hwf[0, 0]:g} x {hwf[0, 1]:g}")
  focal = hwf[0, 2] * scale

  c2w = np.concatenate([matrices[:, :, 1:2], -matrices[:, :, 0:1], matrices[:, :, 2:4]], axis=2)
  tracks = colmap_model.beside(path, c2w, _model_names(path, len(c2w)), table_path)
  points = None if tracks is None else tracks[0]
  if recenter:
    frame, centre = _average_camera(c2w)
    c2w = _recenter(c2w)
    points = None if points is None else (points - centre) @ frame
  if bd_factor:
    rescale = 1.0 / (bd_factor * bounds[:, 0].min())
    c2w[:, :, 3] *= rescale
    bounds = bounds * rescale
    points = None if points is None else points * rescale
  own = {} if tracks is None else {"points": points.astype(np.float32),
                                   "point_errors": tracks[1].astype(np.float32),
                                   "observations": tracks[2]}
  return Dataset(images.astype(np.float32), validate.poses(c2w, table_path),
                 (float(focal), float(focal), width * 0.5, height * 0.5),
                 near=float(bounds[:, 0].min()), far=float(bounds[:, 1].max()), name=path,
                 forward_facing=True, masks=masks, bounds=bounds.astype(np.float32), **own)


def _model_names(path, num_views):
  """The names a COLMAP model beside the LLFF folder is matched by (colmap_model.beside): images/'
  sorted names, row k the k-th (the names COLMAP saw); None (the model's images in name order,
  LLFF's imgs2poses rule) where images/ does not hold num_views images."""
  folder = os.path.join(path, "images")
  names = sorted(n for n in os.listdir(folder) if n.lower().endswith(_IMAGE_SUFFIXES)) if (
      os.path.isdir(folder)) else []
  return names if len(names) == num_views else None
