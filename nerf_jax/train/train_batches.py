"""Training batches: every training pixel on the device, and each step's batch drawn from it.

Training data live on the device as flat per-pixel arrays (see `TrainData`); every step draws its
own batch inside the jitted step from a key folded with the step number, so there is no host
work or host-device transfer per step and a resumed run draws exactly the batches it would have.
"""

import dataclasses

import flax.struct
import jax
import jax.numpy as jnp

from nerf_jax.render import background
from nerf_jax.cameras.rays import Rays, pixel_rays


@dataclasses.dataclass(frozen=True)
class BatchSettings:
  """How each step's rays are drawn (the config's train section).

  batching: 'rays' (batch_rays random pixels of all images) or 'images' (images_per_step whole
  images). image_order: with 'images', 'random' (drawn each step) or 'epochs' (every image once
  per epoch, in an order drawn from the epoch number).
  """
  batching: str = "rays"
  batch_rays: int = 1024
  images_per_step: int = 1
  image_order: str = "random"


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
    of `rays.pixel_rays` that every image shares (with rays None).
  with_radii: static, the rays made per step carry their radii (pixel_rays' with_radii).
  """
  rays: Rays
  rgb: jnp.ndarray
  acc: jnp.ndarray
  poses: jnp.ndarray = None
  image: jnp.ndarray = None
  pixel: jnp.ndarray = None
  camera: tuple = flax.struct.field(pytree_node=False, default=None)
  with_radii: bool = flax.struct.field(pytree_node=False, default=False)


def make_train_data(ds, camera, rgb_background, with_radii=False):
  """TrainData of every pixel of the images of `ds` (a Dataset), targets on `rgb_background`
  (float32 [3], background.parse's); rays are made per step from the poses and `camera`:
  (height, width, intrinsics, near, far, pixel_center, use_ndc), see TrainData.camera
  (run/components.make_train_data passes the training camera's). with_radii: see TrainData."""
  height, width, intrinsics, near, far, pixel_center, use_ndc = camera
  camera = (height, width, tuple(float(v) for v in intrinsics), float(near), float(far),
            float(pixel_center), bool(use_ndc))
  acc, rgb = _targets(ds, rgb_background)
  return TrainData(rays=None, rgb=jnp.asarray(rgb, jnp.float32).reshape(len(ds), -1, 3),
                   acc=jnp.asarray(acc, jnp.float32).reshape(len(ds), -1),
                   poses=jnp.asarray(ds.poses, jnp.float32), camera=camera,
                   with_radii=bool(with_radii))


def pixel_rays_of(data, image, pixel, poses=None):
  """Rays [B] of pixels `pixel` (int32 [B], row-major index in its image) of images `image`
  (int32 [B]), made from `poses` (float32 [N, 4, 4]; None = data.poses: the train step passes
  the refined cameras) and data.camera."""
  poses = data.poses if poses is None else poses
  height, width, intrinsics, near, far, pixel_center, use_ndc = data.camera
  i = (pixel % width).astype(jnp.float32)
  j = (pixel // width).astype(jnp.float32)
  one = lambda i, j, c2w: pixel_rays(i, j, height, width, intrinsics, c2w, near, far,
                                     pixel_center, use_ndc, data.with_radii)
  return jax.vmap(one)(i, j, poses[image])


def _targets(ds, rgb_background):
  """(acc float32 [N, H, W], rgb float32 [N, H, W, 3]): the images of `ds` (a Dataset) on
  `rgb_background` (float32 [3]; see background.images_on_background)."""
  return background.images_on_background(ds, rgb_background)


def draw_batch(data, settings, key, step=0, run_key=None):
  """One step's pixels: a TrainData whose fields are flattened to [B, ...].

  settings: BatchSettings. key: this step's PRNG key. step: int32 [], the step number. run_key:
  the run's PRNG key, used by image_order='epochs' (whole-image batching), where every epoch
  visits each training image once in an order drawn from the epoch number, dropping the
  remainder (as the Keras reference's batch(drop_remainder=True) epochs do).
  """
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
  else:
    idx = jax.random.randint(key, (settings.batch_rays,), 0, num_images * num_pixels)
    take = lambda a: a.reshape(-1, *a.shape[2:])[idx]
    image, pixel = idx // num_pixels, idx % num_pixels
  rays = (jax.tree_util.tree_map(take, data.rays) if data.rays is not None else
          pixel_rays_of(data, image, pixel))
  return TrainData(rays=rays, rgb=take(data.rgb), acc=take(data.acc),
                   image=image.astype(jnp.int32), pixel=pixel.astype(jnp.int32))


def rays_per_step(settings, height, width):
  """Rays in one train step of BatchSettings `settings` on images of height x width: a batch
  of random rays, or whole images."""
  if settings.batching == "images":
    return settings.images_per_step * height * width
  return settings.batch_rays
