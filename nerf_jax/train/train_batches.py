"""Training batches: every training pixel on the device, and each step's batch drawn from it.

Training data live on the device as flat per-pixel arrays (see `TrainData`); every step draws its
own batch inside the jitted step from a key folded with the step number, so there is no host
work or host-device transfer per step and a resumed run draws exactly the batches it would have.

Images of one size are rows of P pixels each; where their intrinsics differ
(`Dataset.image_cameras`: a photo collection posed a camera per photo) each drawn pixel's ray is
made through its image's camera (`cameras`). Images of different sizes are one flat run of every
pixel, image after image: a drawn pixel's image is found from `offsets`; only random rays can be
drawn from them (batching='rays').

With batching='patches' a batch is square patches of P x P neighbouring pixels, each from one
image, patch after patch, each row-major (RobustNeRF's patches: a loss term can look at a
pixel's neighbours, train/losses/robust.py).

Keypoints (`Keypoints`, with a loss term that asks for them: train/losses/depth.py): each
observation of a sparse point (`Dataset.observations`) projected through its image's camera as
trained, a ray through the exact sub-pixel position and the ray's t at the point; a step draws
its own (`draw_keypoints`) and makes their rays (`keypoint_rays`) as it does its pixels'.

Masks (`Dataset.masks`): a masked pixel is never trained on. Its colour is zeroed before it
reaches the device; random rays are drawn from the kept pixels alone (`TrainData.kept`); whole
images and patches carry it with weight exactly 0 (`TrainData.mask`), so every weighted loss
ignores it. Patches are centred on a kept pixel drawn uniformly from the kept ones (moved inside
the image where the centre is near its edge), so that they cover kept pixels; a drawn batch
carries its pixels' masks (`TrainData.mask` [B]) for the terms' statistics.
"""

import dataclasses

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.render import background
from nerf_jax.cameras import intrinsics_refinement
from nerf_jax.cameras.rays import Rays, pixel_rays
from nerf_jax.cameras.scene_settings import SceneSettings

INTRINSICS_NEED_ONE_CAMERA = (
    "config.train.intrinsics_refinement=True refines the focal of images that share one camera "
    "(a focal scale each, one lens): this data has cameras of its own per image "
    "(Dataset.image_cameras: sizes or intrinsics that differ); set "
    "config.train.intrinsics_refinement=False")


@dataclasses.dataclass(frozen=True)
class BatchSettings:
  """How each step's rays are drawn (the config's train section).

  batching: 'rays' (batch_rays random pixels of all images), 'images' (images_per_step whole
  images) or 'patches' (batch_rays // patch_size² random patch_size x patch_size patches, each
  in one image, at least one). image_order: with 'images', 'random' (drawn each step) or
  'epochs' (every image once per epoch, in an order drawn from the epoch number).
  """
  batch_rays: int = 512  # rays per step (random rays over all training images)
  batching: str = "rays"  # 'rays' (random rays), 'images' (whole), 'patches' (loss.robust: always)
  images_per_step: int = 5  # whole images per step when batching == 'images'
  image_order: str = "random"  # 'images' batching: 'random' draws per step, 'epochs' shuffles
  patch_size: int = 16  # patches (loss.robust on): batch_rays // patch_size² squares a step

  def __post_init__(self):
    if self.batching == "patches" and self.patch_size < 1:
      raise ValueError(f"config.train.patch_size={self.patch_size}: a patch has at least one "
                       "pixel a side (RobustNeRF: 16)")

  def num_patches(self):
    """Patches per step with batching 'patches': batch_rays // patch_size², at least one."""
    return max(self.batch_rays // self.patch_size ** 2, 1)


@flax.struct.dataclass
class TrainData:
  """Training pixels, one row per image (P = H·W pixels each).

  rays: Rays [N, P], every pixel's ray; or None: each step makes the rays of the pixels it
    draws from `poses` and `camera` (what make_train_data does: 44 bytes per pixel less, which
    at 800 x 800 x 80 views is 2.3 GB).
  rgb: float32 [N, P, 3], target colours composited on the configured background.
  acc: float32 [N, P], ground-truth opacity (ones where unknown), for random backgrounds.
  poses: float32 [N, 4, 4], camera-to-world of each image (with rays None).
  image, pixel: int32 [B], in a drawn batch (`draw_batch`) the training image of each ray (for
    its appearance code and its camera's correction) and the pixel's row-major index in it.
  camera: static (height, width, intrinsics, near, far, pixel_center, use_ndc): the arguments
    of `rays.pixel_rays` that every image shares (with rays None); with images of different
    sizes height, width and intrinsics are None; with per-image cameras of one size the
    intrinsics are image 0's (`cameras` makes the rays).
  offsets: int32 [N] or None: with images of different sizes, the flat index of each image's
    first pixel; rgb is then float32 [T, 3] and acc float32 [T], T the pixels of all images.
  cameras: float32 [N, 6] or None: with per-image cameras, (fx, fy, cx, cy, width, height).
  lossmult: float32 [N] or None, each image's weight in the colour loss (Dataset.lossmult).
  weight: float32 [B] or None, in a drawn batch each ray's loss weight (its image's lossmult).
  with_radii: static, the rays made per step carry their radii (pixel_rays' with_radii), each
    from its own image's camera.
  kept: int32 [K] or None: with masks, the flat index (into rgb's [N * P] or [T] pixels) of each
    kept pixel; random rays are drawn from these alone.
  mask: float32 [N, P] (or [T]) or None: with masks, 1 for a kept pixel, 0 for a masked one;
    whole-image and patch batches weight each ray by it. In a drawn batch float32 [B], each
    drawn pixel's (LossInputs.mask).
  bounds: float32 [N, 2] or None: each image's own (near, far) z-depths (Dataset.bounds, with
    data.photo_bounds): every ray of the image is sampled between them, not the shared camera's.
  keypoints: Keypoints [K] or None: the sparse points' observations in the training images
    (make_train_data's `keypoints`); None when no loss term asks for them.
  """
  rays: Rays
  rgb: jnp.ndarray
  acc: jnp.ndarray
  poses: jnp.ndarray = None
  image: jnp.ndarray = None
  pixel: jnp.ndarray = None
  camera: tuple = flax.struct.field(pytree_node=False, default=None)
  offsets: jnp.ndarray = None
  cameras: jnp.ndarray = None
  lossmult: jnp.ndarray = None
  weight: jnp.ndarray = None
  with_radii: bool = flax.struct.field(pytree_node=False, default=False)
  kept: jnp.ndarray = None
  mask: jnp.ndarray = None
  bounds: jnp.ndarray = None
  keypoints: "Keypoints" = None


@flax.struct.dataclass
class Keypoints:
  """Observations of the sparse points: K keypoints, each a training image's view of one point.

  image: int32 [K], the training image. at: float32 [K, 2], (column i, row j) of the ray through
    the point, as `rays.pixel_rays` takes them (sub-pixel: the point projected through the
    image's camera, pixel centre offset included).
  t: float32 [K], the ray's t at the point: its z-depth, or in NDC s = 1 - NDC_NEAR / depth
    (cameras/ndc.py; depth the point's -z in world).
  scale: float32 [K], depth · dt/d depth at the point: how far t moves when the depth grows by a
    share of itself, per unit share (the depth itself; NDC_NEAR / depth in NDC): a depth spread
    given as a share of the depth is that share times `scale` in t.
  error: float32 [K], the point's reprojection error over the mean error of the points kept
    (1 where the data does not know it or the mean is 0).
  """
  image: jnp.ndarray
  at: jnp.ndarray
  t: jnp.ndarray
  scale: jnp.ndarray
  error: jnp.ndarray

  def __len__(self):
    return self.t.shape[0]


NDC_NEAR = 1.0  # the world plane z = -1 where pixel_rays' NDC rays start (ndc_rays' near there)


def make_train_data(ds, camera, rgb_background, with_radii=False,
                    photo_bounds=SceneSettings.photo_bounds, keypoints=False):
  """TrainData of every pixel of the images of `ds` (a Dataset), targets on `rgb_background`
  (float32 [3], background.parse's); rays are made per step from the poses and `camera`:
  (height, width, intrinsics, near, far, pixel_center, use_ndc), see TrainData.camera
  (run/builders.make_train_data passes the training camera's). With per-image cameras
  (`ds.image_cameras`) the pixels are one flat run and each image's own camera is used (its
  height, width and intrinsics in `camera` are ignored). with_radii: see TrainData.
  photo_bounds: each image's rays between its own bounds (TrainData.bounds; ds.bounds must be
  set). keypoints: fill TrainData.keypoints from ds.observations (`keypoints_of`; ds must have
  them)."""
  data = _pixel_data(ds, camera, rgb_background, with_radii, photo_bounds)
  return data.replace(keypoints=keypoints_of(data, ds)) if keypoints else data


def _pixel_data(ds, camera, rgb_background, with_radii, photo_bounds):
  """make_train_data's TrainData without keypoints."""
  height, width, intrinsics, near, far, pixel_center, use_ndc = camera
  lossmult = None if ds.lossmult is None else jnp.asarray(ds.lossmult, jnp.float32)
  if photo_bounds and ds.bounds is None:
    raise ValueError("config.data.photo_bounds: the data has no per-photo bounds (LLFF's, or "
                     "data.subject's)")
  bounds = jnp.asarray(ds.bounds, jnp.float32) if photo_bounds else None
  if ds.mixed_sizes:
    data = _flat_train_data(ds, (None, None, None, float(near), float(far),
                                 float(pixel_center), bool(use_ndc)), rgb_background, lossmult,
                            with_radii)
    return _with_masks(data.replace(bounds=bounds), ds)
  camera = (height, width, tuple(float(v) for v in intrinsics), float(near), float(far),
            float(pixel_center), bool(use_ndc))
  acc, rgb = _targets(ds, rgb_background)
  data = TrainData(rays=None, rgb=jnp.asarray(rgb, jnp.float32).reshape(len(ds), -1, 3),
                   acc=jnp.asarray(acc, jnp.float32).reshape(len(ds), -1),
                   poses=jnp.asarray(ds.poses, jnp.float32), camera=camera, lossmult=lossmult,
                   with_radii=bool(with_radii), bounds=bounds,
                   cameras=None if ds.image_cameras is None else _camera_table(ds.cameras))
  return _with_masks(data, ds)


def _with_masks(data, ds):
  """`data` with the `kept` and `mask` of the masks of `ds` (module docstring; `_targets` has
  zeroed the masked colours); `data` itself when ds has no masks."""
  if ds.masks is None:
    return data
  mask = np.concatenate([np.reshape(m, -1) for m in ds.masks]).astype(np.float32)
  return data.replace(kept=jnp.asarray(np.flatnonzero(mask), jnp.int32),
                      mask=jnp.asarray(mask.reshape(data.rgb.shape[:-1]), jnp.float32))


def _camera_table(cams):
  """float32 [N, 6] of Cameras `cams`: (fx, fy, cx, cy, width, height) of each image."""
  table = np.concatenate([cams.table(), np.stack([cams.width, cams.height], -1)], -1)
  return jnp.asarray(table, jnp.float32)


def _flat_train_data(ds, camera, rgb_background, lossmult, with_radii):
  """TrainData of `ds`'s images of different sizes: every pixel in one flat run."""
  acc, rgb = _targets(ds, rgb_background)
  cams = ds.cameras
  counts = cams.num_pixels()
  offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
  return TrainData(rays=None,
                   rgb=jnp.asarray(np.concatenate([np.reshape(a, (-1, 3)) for a in rgb]),
                                   jnp.float32),
                   acc=jnp.asarray(np.concatenate([np.reshape(a, -1) for a in acc]),
                                   jnp.float32),
                   poses=jnp.asarray(ds.poses, jnp.float32), camera=camera,
                   offsets=jnp.asarray(offsets, jnp.int32),
                   cameras=_camera_table(cams), lossmult=lossmult,
                   with_radii=bool(with_radii))


def pixel_rays_of(data, image, pixel, poses=None, intrinsics=None):
  """Rays [B] of pixels `pixel` (int32 [B], row-major index in its image) of images `image`
  (int32 [B]), made from `poses` (float32 [N, 4, 4]; None = data.poses: the train step passes
  the refined cameras) and data.camera; with `intrinsics` (params['intrinsics'] of
  cameras/intrinsics_refinement.py) each through its image's refined focal and the shared
  lens (images of one camera only: ValueError with per-image cameras); each between its image's
  own bounds where data.bounds is set."""
  rays = _pixel_rays(data, image, pixel, poses, intrinsics)
  if data.bounds is None:
    return rays
  return rays.replace(near=data.bounds[image, 0], far=data.bounds[image, 1])


def _pixel_rays(data, image, pixel, poses, intrinsics):
  """pixel_rays_of's rays between the shared camera's near and far."""
  width = data.camera[1] if data.cameras is None else data.cameras[image][:, 4].astype(jnp.int32)
  i = (pixel % width).astype(jnp.float32)
  j = (pixel // width).astype(jnp.float32)
  return _rays_at(data, image, i, j, poses, intrinsics)


def _rays_at(data, image, i, j, poses, intrinsics):
  """Rays [B] through (column i, row j) (float32 [B], `rays.pixel_rays`' pixel coordinates) of
  images `image` (int32 [B]), between the shared camera's near and far (see pixel_rays_of)."""
  poses = data.poses if poses is None else poses
  height, width, pinhole, near, far, pixel_center, use_ndc = data.camera
  if intrinsics is not None and data.cameras is not None:
    raise ValueError(INTRINSICS_NEED_ONE_CAMERA)
  if data.cameras is not None:  # each ray through its own image's camera
    cams = data.cameras[image]

    def one(i, j, c2w, cam):  # cam: fx, fy, cx, cy, width, height
      return pixel_rays(i, j, cam[5], cam[4], tuple(cam[:4]), c2w, near, far, pixel_center,
                        use_ndc, data.with_radii)
    return jax.vmap(one)(i, j, poses[image], cams)
  if intrinsics is not None:
    one = lambda i, j, c2w, lens: pixel_rays(i, j, height, width, pinhole, c2w, near, far,
                                             pixel_center, use_ndc, data.with_radii, lens)
    return jax.vmap(one)(i, j, poses[image], intrinsics_refinement.lens_of(intrinsics, image))
  one = lambda i, j, c2w: pixel_rays(i, j, height, width, pinhole, c2w, near, far,
                                     pixel_center, use_ndc, data.with_radii)
  return jax.vmap(one)(i, j, poses[image])


def keypoint_rays(data, keypoints, poses=None, intrinsics=None):
  """Rays [R] of `keypoints` (Keypoints [R]): each through its image's camera at its exact
  sub-pixel position, as `pixel_rays_of` makes a pixel's (poses, intrinsics: as there; between
  its image's own bounds where data.bounds is set)."""
  image = keypoints.image
  rays = _rays_at(data, image, keypoints.at[:, 0], keypoints.at[:, 1], poses, intrinsics)
  if data.bounds is None:
    return rays
  return rays.replace(near=data.bounds[image, 0], far=data.bounds[image, 1])


def draw_keypoints(data, count, key):
  """Keypoints [count] drawn uniformly (with replacement) from data.keypoints with `key`."""
  pick = jax.random.randint(key, (count,), 0, len(data.keypoints))
  return jax.tree_util.tree_map(lambda a: a[pick], data.keypoints)


def keypoints_of(data, ds):
  """Keypoints of the observations of `ds` (a Dataset with observations) through the cameras
  of `data` (its TrainData, as make_train_data builds it: the poses, cameras, bounds and NDC the
  rays are made with). Dropped: an observation whose point is behind its camera, outside its
  image (no pixel's ray is nearest it: pixel k spans [k - 0.5, k + 0.5) in `at`) or outside its
  ray's [near, far]; and every observation of a point that a mask hides in any training image
  (Dataset.masks: the point may lie on what the mask hides, a passer-by). Computed in float64
  on the host; K may be 0 (the caller says what that means)."""
  image, point = np.asarray(ds.observations, np.int64).T
  at, t, scale, inside = _project(data, image, np.asarray(ds.points, np.float64)[point])
  if ds.masks is not None:
    hidden = np.zeros(len(ds.points), bool)
    hidden[point[inside & ~_kept_at(ds.masks, image, at, inside)]] = True
    inside &= ~hidden[point]
  errors = np.asarray(ds.point_errors, np.float64)
  known = np.isfinite(errors) & (errors >= 0)  # COLMAP writes -1 for an error it never set
  seen = np.unique(point[inside])
  mean = errors[seen][known[seen]].mean() if known[seen].any() else 0.0
  ratio = np.where(known, errors / mean, 1.0) if mean > 0 else np.ones_like(errors)
  ratio = ratio[point[inside]]
  as32 = lambda a: jnp.asarray(a, jnp.float32)
  return Keypoints(image=jnp.asarray(image[inside], jnp.int32), at=as32(at[inside]),
                   t=as32(t[inside]), scale=as32(scale[inside]), error=as32(ratio))


def _project(data, image, points):
  """(at float64 [K, 2], t float64 [K], scale float64 [K], inside bool [K]) of world `points`
  (float64 [K, 3]) seen from images `image` (int [K]) through data's cameras (Keypoints'
  fields; inside: in front of the camera, in its image, t within the ray's [near, far])."""
  height, width, pinhole, near, far, pixel_center, use_ndc = data.camera
  poses = np.asarray(data.poses, np.float64)[image]
  cam = np.einsum("kji,kj->ki", poses[:, :3, :3], points - poses[:, :3, 3])  # R^T (p - o)
  depth = -cam[:, 2]  # the camera looks down -z
  if data.cameras is not None:
    fx, fy, cx, cy, widths, heights = np.asarray(data.cameras, np.float64)[image].T
  else:
    (fx, fy, cx, cy), widths, heights = pinhole, width, height
  front = depth > 0
  safe = np.where(front, depth, 1.0)  # behind the camera: dropped, any finite value will do
  at = np.stack([fx * cam[:, 0] / safe + cx, -fy * cam[:, 1] / safe + cy], -1) - pixel_center
  # Pixel k's ray is at k (pixel_rays adds pixel_center itself), so the pixel spans
  # [k - 0.5, k + 0.5) in `at`, whatever the data's convention of pixel centres.
  col, row = np.floor(at + 0.5).T
  if use_ndc:  # t along the NDC ray: s = 1 - near / (its world -z) (cameras/ndc.py)
    world_depth = np.where(points[:, 2] < 0, -points[:, 2], np.inf)  # behind z = 0: s = 1
    t, scale = 1.0 - NDC_NEAR / world_depth, NDC_NEAR / world_depth
  else:
    t, scale = depth, depth
  if data.bounds is not None:
    near, far = np.asarray(data.bounds, np.float64)[image].T
  inside = (front & (col >= 0) & (col < widths) & (row >= 0) & (row < heights) & (t > near)
            & (t < far))
  return at, t, scale, inside


def _kept_at(masks, image, at, inside):
  """bool [K]: whether the mask of image `image` keeps the pixel holding each of `at` (float
  [K, 2], pixel_rays' coordinates: pixel k spans [k - 0.5, k + 0.5)); True where not `inside`
  (not looked up)."""
  col, row = np.floor(at + 0.5).astype(np.int64).T
  kept = np.ones(len(image), bool)
  for index in np.unique(image[inside]):  # image by image: masks may differ in size
    here = np.flatnonzero(inside & (image == index))
    kept[here] = np.asarray(masks[index])[row[here], col[here]] > 0
  return kept


def _targets(ds, rgb_background):
  """(acc float32 [N, H, W], rgb float32 [N, H, W, 3]): the images of `ds` (a Dataset) on
  `rgb_background` (float32 [3]; see background.images_on_background), lists with mixed sizes;
  masked pixels (ds.masks) black, so that their colours never reach the device."""
  acc, rgb = background.images_on_background(ds, rgb_background)
  if ds.masks is None:
    return acc, rgb
  # A new array, image by image: `rgb` may be ds.images itself, which must stay as it is.
  zeroed = [None] * len(rgb) if isinstance(rgb, list) else np.empty(np.shape(rgb), np.float32)
  for k, (m, image) in enumerate(zip(ds.masks, rgb)):
    zeroed[k] = np.where(np.asarray(m)[..., None] > 0, image, 0.0).astype(np.float32)
  return acc, zeroed


def draw_batch(data, settings, key, step=0, run_key=None):
  """One step's pixels: a TrainData whose fields are flattened to [B, ...].

  settings: BatchSettings. key: this step's PRNG key. step: int32 [], the step number. run_key:
  the run's PRNG key, used by image_order='epochs' (whole-image batching), where every epoch
  visits each training image once in an order drawn from the epoch number, dropping the
  remainder (as the Keras reference's batch(drop_remainder=True) epochs do).
  With images of different sizes (TrainData.offsets) every pixel of every image is equally
  likely.
  """
  if data.offsets is not None:
    return _draw_flat(data, settings, key)
  num_images, num_pixels = data.rgb.shape[:2]
  if settings.batching == "images":
    per_step = settings.images_per_step
    if settings.image_order == "epochs":
      run_key = key if run_key is None else run_key
      steps_per_epoch = max(num_images // per_step, 1)
      # A stream of its own: fold_in(run_key, n) is already step n's key.
      epochs_key = jax.random.split(run_key)[1]
      order = jax.random.permutation(jax.random.fold_in(epochs_key, step // steps_per_epoch),
                                     num_images)
      images = jax.lax.dynamic_slice(order, ((step % steps_per_epoch) * per_step,), (per_step,))
    else:
      images = jax.random.choice(key, num_images, (per_step,), replace=False)
    take = lambda a: a[images].reshape(-1, *a.shape[2:])
    image = jnp.repeat(images, num_pixels)
    pixel = jnp.tile(jnp.arange(num_pixels), per_step)
    masked = None if data.mask is None else take(data.mask)  # whole images: weight 0
  elif settings.batching == "patches":
    image, pixel = _draw_patches(data, num_images, settings, key)
    idx = image * num_pixels + pixel
    take = lambda a: a.reshape(-1, *a.shape[2:])[idx]
    masked = None if data.mask is None else take(data.mask)  # patches: weight 0
  else:
    idx = _random_pixels(data, key, settings.batch_rays, num_images * num_pixels)
    take = lambda a: a.reshape(-1, *a.shape[2:])[idx]
    image, pixel = idx // num_pixels, idx % num_pixels
    masked = None if data.mask is None else take(data.mask)  # kept pixels alone: all 1
  rays = (jax.tree_util.tree_map(take, data.rays) if data.rays is not None else
          pixel_rays_of(data, image, pixel))
  weight = _ray_weight(data, image, None if settings.batching == "rays" else masked)
  return TrainData(rays=rays, rgb=take(data.rgb), acc=take(data.acc),
                   image=image.astype(jnp.int32), pixel=pixel.astype(jnp.int32),
                   weight=weight, mask=masked)


def _random_pixels(data, key, count, total):
  """int32 [count] flat pixel indices drawn uniformly from the `total` pixels, or from the kept
  ones alone where the data has masks (`TrainData.kept`)."""
  if data.kept is None:
    return jax.random.randint(key, (count,), 0, total)
  return data.kept[jax.random.randint(key, (count,), 0, data.kept.shape[0])]


def _ray_weight(data, image, masked):
  """float32 [B] or None, each drawn ray's loss weight: its image's lossmult times `masked`
  (float32 [B] or None, the drawn pixels' masks); None when neither exists."""
  weight = None if data.lossmult is None else data.lossmult[image]
  if masked is None:
    return weight
  return masked if weight is None else weight * masked


def _draw_patches(data, num_images, settings, key):
  """(image, pixel), each int32 [n · P · P]: n = settings.num_patches() patches of P x P
  pixels (P = settings.patch_size) of the TrainData `data`, patch after patch, each row-major.
  Without masks each is in an image drawn uniformly at a corner drawn uniformly among those
  that keep it inside; with masks (data.kept) each is centred on a kept pixel drawn uniformly
  from all kept pixels (its row and column P // 2 into the patch), the patch moved inside the
  image where that pixel is nearer an edge: every patch holds the kept pixel it was drawn
  from."""
  camera = data.camera
  if camera is None:
    raise ValueError("config.train.batching='patches' draws from images of one camera")
  height, width = camera[:2]
  size = settings.patch_size
  if size > min(height, width):
    raise ValueError(f"config.train.patch_size={size}: larger than the {height} x {width} "
                     "training images")
  count = settings.num_patches()
  image_key, row_key, col_key = jax.random.split(key, 3)
  if data.kept is None:
    images = jax.random.randint(image_key, (count,), 0, num_images)
    rows = jax.random.randint(row_key, (count, 1, 1), 0, height - size + 1)
    cols = jax.random.randint(col_key, (count, 1, 1), 0, width - size + 1)
  else:
    centre = data.kept[jax.random.randint(image_key, (count,), 0, data.kept.shape[0])]
    images, centre = centre // (height * width), centre % (height * width)
    corner = lambda at, side: jnp.clip(at - size // 2, 0, side - size)[:, None, None]
    rows, cols = corner(centre // width, height), corner(centre % width, width)
  dy, dx = jnp.meshgrid(jnp.arange(size), jnp.arange(size), indexing="ij")
  pixel = ((rows + dy) * width + cols + dx).reshape(-1)
  return jnp.repeat(images, size * size), pixel


def _draw_flat(data, settings, key):
  """draw_batch of images of different sizes: batch_rays pixels drawn uniformly over all
  images."""
  if settings.batching != "rays":
    raise ValueError(f"config.train.batching={settings.batching!r}: images of different sizes "
                     "train on random rays: use 'rays'")
  idx = _random_pixels(data, key, settings.batch_rays, data.rgb.shape[0])
  image = (jnp.searchsorted(data.offsets, idx, side="right") - 1).astype(jnp.int32)
  pixel = (idx - data.offsets[image]).astype(jnp.int32)
  return TrainData(rays=pixel_rays_of(data, image, pixel), rgb=data.rgb[idx],
                   acc=data.acc[idx], image=image, pixel=pixel,
                   weight=_ray_weight(data, image, None),
                   mask=None if data.mask is None else data.mask[idx])


def rays_per_step(settings, height, width):
  """Rays in one train step of BatchSettings `settings` on images of height x width: a batch
  of random rays, whole images, or whole patches."""
  if settings.batching == "images":
    return settings.images_per_step * height * width
  if settings.batching == "patches":
    return settings.num_patches() * settings.patch_size ** 2
  return settings.batch_rays
