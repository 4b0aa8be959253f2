"""A set of posed images, the common output of every loader and built-in scene."""

import dataclasses
from typing import Optional

import numpy as np

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data import one_camera as one_camera_lib

MIN_SHARED = 3  # fewer images than this sharing image 0's camera: a camera per photo


class DataError(ValueError):
  """Bad or missing input data; the one-line message names the file or field at fault."""


@dataclasses.dataclass
class Dataset:
  """Posed images of one scene (conventions of `nerf_jax.cameras.rays`).

  images: float32 [N, H, W, 3] in [0, 1], composited on the background, when every image has
    the same size; images of different sizes (mip-NeRF's multiscale data): a list of N float32
    [H_i, W_i, 3] arrays, and `accs`, `depths` lists of [H_i, W_i] arrays likewise. `image(i)`,
    `acc(i)` read either form.
  poses: float32 [N, 4, 4], camera-to-world.
  intrinsics: (fx, fy, cx, cy) in pixels: the camera of every image, or with per-image cameras
    that of image 0 (what shared-camera code uses: previews, camera paths, the viewer).
  image_cameras: Cameras or None: each image's own size and intrinsics where they differ
    between images; None = every image has `intrinsics` and the images' size. Read `cameras`
    (always present). A Cameras whose entries are all the same is dropped (one camera).
  lossmult: float32 [N] or None, the weight of each image's pixels in the colour loss
    (mip-NeRF's multiscale data: 4^level, so that every scale counts equally).
  labels: str array [N] or None, each image's scale label (multiscale data: '0', '1', ...):
    the evaluation also scores each label apart (metrics.json's by_scale).
  near, far: float, z-depth bounds of the scene.
  depths: float32 [N, H, W] or None, ground-truth expected depth (built-in scenes only).
  accs: float32 [N, H, W] or None, opacity of each pixel over the background: ground truth for
    built-in scenes, the alpha channel of RGBA files, None when unknown (RGB files, LLFF).
  name: str, the scene or file it came from.
  background: (r, g, b), the colour `images` are composited on, so that
    `images + (1 - accs) * (new - background)` re-composites them on `new`; (0, 0, 0) when
    unknown.
  forward_facing: bool, all cameras look roughly down world -z at content beyond z = -near
    (LLFF captures, the 'forward' scene): the case for NDC rays (`nerf_jax.cameras.ndc`).
  pixel_center: float, where in its pixel each image was sampled (`cameras.rays`): 0.5 (pixel
    centres: rendered or photographed images, the default), 0 (pixel corners: tiny_nerf's .npz
    as the Keras reference reads it).
  aabb: float32 [2, 3] or None, (min, max) corner in world units of the box the data says holds
    the scene (transforms.json: instant-ngp's aabb_scale, else the sparse points); scene-wide,
    so subsets keep it. None when the data does not say.
  core: float32 [2, 3] or None, the box of the subject within it (instant-ngp's unit cube, else
    the sparse points' box): the inner region of an unbounded scene. None when unknown.
  true_poses: float32 [N, 4, 4] or None, the poses the images were really taken from where they
    differ from `poses` and the data knows them (a simulated pose error, scenes/photos.py).
  masks: float32 [N, H, W] or None (a list of [H_i, W_i] with mixed sizes, as `images`): 1 where
    a pixel shows the scene (kept), 0 where it must be ignored (a passer-by, a car): a masked
    pixel is neither trained on nor scored (data/masks.py, docs/masks.md). None = keep all.
  points: float32 [P, 3] or None, the sparse points of structure from motion in world units
    (nerfstudio's ply_file_path); scene-wide, so subsets keep them. None when the data has none.
  bounds: float32 [N, 2] or None, each image's own (near, far) z-depths (LLFF's poses_bounds);
    `near`, `far` cover them all. The samplers read only `near`, `far`. None when unknown.
  point_errors: float32 [P] or None, each of `points`' mean reprojection error in pixels
    (COLMAP's ERROR; < 0 or NaN where unknown); scene-wide, as `points`. None without tracks.
  observations: int32 [K, 2] or None, the sparse points' tracks: (image index, point index)
    pairs, point p of `points` seen in image i, each pair once; subsets keep the pairs of the
    images they keep, re-indexed (`subset`). The keypoint's pixel and depth are not stored: they
    are the point projected through the image's camera as trained (train_batches.Keypoints),
    so every move of the world and every change of the cameras keeps them. None without tracks
    (a COLMAP model's images and points3D: colmap.py, and beside transforms.json or LLFF).
  """
  images: np.ndarray
  poses: np.ndarray
  intrinsics: tuple
  near: float = 2.0
  far: float = 6.0
  depths: Optional[np.ndarray] = None
  accs: Optional[np.ndarray] = None
  name: str = ""
  background: tuple = (0.0, 0.0, 0.0)
  forward_facing: bool = False
  pixel_center: float = 0.5
  aabb: Optional[np.ndarray] = None
  core: Optional[np.ndarray] = None
  true_poses: Optional[np.ndarray] = None
  image_cameras: Optional[Cameras] = None
  lossmult: Optional[np.ndarray] = None
  labels: Optional[np.ndarray] = None
  masks: Optional[np.ndarray] = None
  points: Optional[np.ndarray] = None
  bounds: Optional[np.ndarray] = None
  point_errors: Optional[np.ndarray] = None
  observations: Optional[np.ndarray] = None

  def __post_init__(self):
    if self.image_cameras is not None and self.image_cameras.is_shared() and not isinstance(
        self.images, list):
      height, width, intrinsics = self.image_cameras.camera(0)
      if (height, width) == tuple(self.images.shape[1:3]):
        self.intrinsics, self.image_cameras = intrinsics, None
    if self.image_cameras is not None:
      self.intrinsics = self.image_cameras.camera(0)[2]
    if self.labels is not None:
      self.labels = np.asarray([str(v) for v in self.labels])
    if self.lossmult is not None:
      self.lossmult = np.asarray(self.lossmult, np.float32).reshape(-1)
    if self.masks is not None:
      self.masks = self._checked_masks(self.masks)
    if self.observations is not None:
      self._check_tracks()

  def _check_tracks(self):
    """DataError unless `observations` pair images and points that exist and `point_errors`
    has one entry per point."""
    obs = np.asarray(self.observations)
    if obs.ndim != 2 or obs.shape[1] != 2:
      raise DataError(f"{self.name}: observations has shape {obs.shape}, not [K, 2]")
    num_points = 0 if self.points is None else len(self.points)
    if self.point_errors is None or len(self.point_errors) != num_points:
      raise DataError(f"{self.name}: observations need points and point_errors of one length "
                      f"(points: {num_points}, point_errors: "
                      f"{None if self.point_errors is None else len(self.point_errors)})")
    if len(obs) and not (0 <= obs.min() and obs[:, 0].max() < len(self.images)
                         and obs[:, 1].max() < num_points):
      raise DataError(f"{self.name}: observations name an image or a point that does not "
                      f"exist ({len(self.images)} images, {num_points} points)")

  def _checked_masks(self, masks):
    """`masks` as float32 of 0 and 1 (an array, or a list with mixed sizes); DataError for NaN,
    values other than 0 and 1, a size unlike its image's or an image with every pixel masked."""
    as_mask = lambda m: np.asarray(m, np.float32)
    masks = [as_mask(m) for m in masks] if isinstance(masks, list) else as_mask(masks)
    if len(masks) != len(self.images):
      raise DataError(f"{self.name}: {len(masks)} masks for {len(self.images)} images")
    for k, (mask, image) in enumerate(zip(masks, self.images)):
      if mask.shape != image.shape[:2]:
        raise DataError(f"{self.name}: mask {k} is {mask.shape}, its image {image.shape[:2]}")
      if not np.all((mask == 0) | (mask == 1)):  # NaN fails both
        raise DataError(f"{self.name}: mask {k} holds values other than 0 and 1 (or NaN)")
      if not mask.any():
        raise DataError(f"{self.name}: mask {k} ignores every pixel of its image")
    return masks

  @property
  def cameras(self):
    """Cameras: every image's size and intrinsics (built from `intrinsics` with one camera)."""
    if self.image_cameras is not None:
      return self.image_cameras
    return Cameras.shared(len(self), self.height, self.width, self.intrinsics)

  @property
  def mixed_sizes(self):
    """Whether the images differ in size (`images` is then a list)."""
    return isinstance(self.images, list)

  def image(self, index):
    """float32 [H_i, W_i, 3], image `index`."""
    return self.images[index]

  def acc(self, index):
    """float32 [H_i, W_i] or None, the opacity of image `index`."""
    return None if self.accs is None else self.accs[index]

  def mask(self, index):
    """float32 [H_i, W_i] or None, the mask of image `index` (1 keep, 0 ignore)."""
    return None if self.masks is None else self.masks[index]

  @property
  def height(self):
    return self.images[0].shape[0]

  @property
  def width(self):
    return self.images[0].shape[1]

  @property
  def focal(self):
    return self.intrinsics[0]

  def pinhole_focal(self):
    """The single focal length; DataError unless the intrinsics are a centred pinhole (what the
    tiny_nerf, Blender and LLFF formats can store)."""
    if self.image_cameras is not None:
      raise DataError(f"{self.name}: the images have cameras of their own (sizes or intrinsics "
                      "that differ); the format stores one camera: write mip-NeRF's multiscale "
                      "format instead (python -m nerf_jax.data.export --format=multiscale)")
    fx, fy, cx, cy = self.intrinsics
    if fx != fy or cx != self.width * 0.5 or cy != self.height * 0.5:
      raise DataError(f"{self.name}: intrinsics {self.intrinsics} are not a centred pinhole "
                      "camera; the format cannot store them")
    return float(fx)

  def moved(self, centre, scale=1.0):
    """This Dataset with the world mapped by x -> scale (x - centre) (centre float [3], scale
    float > 0): the cameras' centres (poses, true_poses), the boxes (aabb, core) and the sparse
    points move; every length (near, far, bounds, depths) is times scale, and stays as it is
    with scale 1 (a move keeps z-depths). Rotations, cameras, images and the tracks (indices,
    errors in pixels) stay. Computed in float64, stored float32 (a float64 sum of float32
    values rounds to float32's own sum: a pure move by a float32 centre is float32 arithmetic)."""
    centre = np.asarray(centre, np.float64)
    move = lambda a: None if a is None else (
        scale * (np.asarray(a, np.float64) - centre)).astype(np.float32)
    def move_poses(poses):
      if poses is None:
        return None
      poses = np.array(poses, np.float64)
      poses[:, :3, 3] = scale * (poses[:, :3, 3] - centre)
      return poses.astype(np.float32)
    def times(a):
      if a is None or scale == 1:
        return a
      if isinstance(a, list):  # mixed sizes
        return [(scale * np.asarray(d)).astype(np.float32) for d in a]
      return (scale * np.asarray(a, np.float64)).astype(np.float32)
    return dataclasses.replace(
        self, poses=move_poses(self.poses), true_poses=move_poses(self.true_poses),
        aabb=move(self.aabb), core=move(self.core), points=move(self.points),
        near=float(scale * self.near), far=float(scale * self.far), bounds=times(self.bounds),
        depths=times(self.depths))

  def one_camera(self):
    """The images that share image 0's camera, as a Dataset of one camera (`images` an [M, H,
    W, 3] array, image_cameras None): what code that reads the images of one camera takes
    (config=auto's measurements, the visual hull); `self` when it has one camera. Where fewer
    than MIN_SHARED images share it (a photo collection: a camera per photo), every image
    resampled into one pinhole instead (data/one_camera.py)."""
    return one_camera_lib.shared_or_resampled(self, MIN_SHARED)

  def __len__(self):
    return len(self.images)

  def subset(self, indices):
    """The views `indices` (int array, slice or list), as a new Dataset."""
    take = lambda a: None if a is None else _take(a, indices)
    cameras = None if self.image_cameras is None else self.image_cameras.subset(indices)
    return dataclasses.replace(self, images=_take(self.images, indices),
                               poses=self.poses[indices], depths=take(self.depths),
                               accs=take(self.accs), true_poses=take(self.true_poses),
                               image_cameras=cameras, lossmult=take(self.lossmult),
                               labels=take(self.labels), masks=take(self.masks),
                               bounds=take(self.bounds),
                               observations=_observations_of(self.observations, len(self),
                                                             indices))

  def split(self, holdout_from=-1):
    """(train, test): views [:holdout_from] and [holdout_from:].

    holdout_from: int in [1, N - 1], or -1 for the reference's split (train = first 80%).
    """
    num = len(self)
    cut = int(0.8 * num) if holdout_from == -1 else holdout_from
    if not 1 <= cut <= num - 1:
      raise DataError(f"{self.name}: holdout_from={holdout_from} leaves an empty split of "
                      f"{num} views (use -1 or 1..{num - 1})")
    return self.subset(slice(0, cut)), self.subset(slice(cut, num))

  def split_every(self, every=8):
    """(train, test): test = views 0, every, 2 * every, ... (the LLFF convention), train = the
    others."""
    num = len(self)
    if every < 2 or num < 2:
      raise DataError(f"{self.name}: cannot hold out every {every}th of {num} views")
    is_test = np.arange(num) % every == 0
    return self.subset(np.flatnonzero(~is_test)), self.subset(np.flatnonzero(is_test))


def _observations_of(observations, num, indices):
  """int32 [K', 2]: the pairs of `observations` (int32 [K, 2] or None: None stays None) of the
  images `indices` (of `num`), image indices renumbered to the subset's (an image taken twice
  has its pairs twice)."""
  if observations is None:
    return None
  obs = np.asarray(observations, np.int32)
  kept = np.arange(num)[indices]
  order = np.argsort(obs[:, 0], kind="stable")
  first = np.searchsorted(obs[order, 0], kept, side="left")
  last = np.searchsorted(obs[order, 0], kept, side="right")
  parts = [np.stack([np.full(b - a, new, np.int32), obs[order[a:b], 1]], -1)
           for new, (a, b) in enumerate(zip(first, last))]
  return np.concatenate(parts).astype(np.int32) if parts else np.zeros((0, 2), np.int32)


def _take(values, indices):
  """values[indices] of an array, or of a list (a list back)."""
  if not isinstance(values, list):
    return values[indices]
  return [values[k] for k in np.arange(len(values))[indices]]
