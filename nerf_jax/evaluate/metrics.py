"""Image quality metrics. Images are float32 [..., H, W, 3] in [0, 1].

Masks (`Dataset.masks`, docs/masks.md): mask float32 [..., H, W], 1 where a pixel is scored, 0
where it is not. PSNR is then over the kept pixels, SSIM the mean of its map over the map
positions whose window centre is a kept pixel (`ssim_map`).
"""

import jax
import jax.numpy as jnp

from nerf_jax.backend import precision


def mse_to_psnr(mse):
  """PSNR in dB for a peak of 1; mse clamped at 1e-10 so a perfect match gives 100 dB, not inf."""
  return -10.0 * jnp.log10(jnp.maximum(mse, 1e-10))


def psnr(image, reference, mask=None):
  """PSNR per image: float32 [...] from images float32 [..., H, W, C]; with mask (float32
  [..., H, W], module docstring) over the kept pixels alone (NaN for an image with none)."""
  error = (image - reference) ** 2
  if mask is None:
    return mse_to_psnr(jnp.mean(error, axis=(-3, -2, -1)))
  mask = jnp.asarray(mask, jnp.float32)
  kept = jnp.sum(mask, axis=(-2, -1)) * error.shape[-1]
  mse = jnp.sum(error * mask[..., None], axis=(-3, -2, -1)) / jnp.maximum(kept, 1.0)
  return jnp.where(kept > 0, mse_to_psnr(mse), jnp.nan)  # max: no 0/0 where nothing is kept


def _gaussian_kernel(size=11, sigma=1.5):
  x = jnp.arange(size, dtype=jnp.float32) - (size - 1) / 2
  k = jnp.exp(-0.5 * (x / sigma) ** 2)
  return k / jnp.sum(k)


def _blur(x, kernel):
  """'Valid' separable filtering of x: float32 [H, W, C] with kernel: float32 [K]."""
  conv = lambda v: precision.convolve(v, kernel, mode="valid")  # full float32: a metric
  x = jax.vmap(jax.vmap(conv, in_axes=1, out_axes=1), in_axes=2, out_axes=2)(x)  # along H
  return jax.vmap(jax.vmap(conv, in_axes=0, out_axes=0), in_axes=2, out_axes=2)(x)  # along W


SSIM_WINDOW = 11  # the Gaussian window's side; map position (i, j) is pixel (i + 5, j + 5)'s


def _ssim_terms(image, reference):
  """float32 [H - 10, W - 10, C]: SSIM of each valid 11 x 11 window of image and reference
  (float32 [H, W, C]) and channel."""
  c1, c2 = 0.01 ** 2, 0.03 ** 2  # Wang et al. (2004) constants for a dynamic range of 1
  k = _gaussian_kernel(SSIM_WINDOW)
  mu_x, mu_y = _blur(image, k), _blur(reference, k)
  var_x = _blur(image * image, k) - mu_x ** 2
  var_y = _blur(reference * reference, k) - mu_y ** 2
  cov = _blur(image * reference, k) - mu_x * mu_y
  num = (2 * mu_x * mu_y + c1) * (2 * cov + c2)
  den = (mu_x ** 2 + mu_y ** 2 + c1) * (var_x + var_y + c2)
  return num / den  # den >= c1·c2 > 0


@jax.jit
def _ssim_single(image, reference):
  return jnp.mean(_ssim_terms(image, reference))


@jax.jit
def _masked_ssim_single(image, reference, mask):
  """The mean of the SSIM map over the positions whose window centre mask [H, W] keeps (NaN
  where none is kept)."""
  half = SSIM_WINDOW // 2
  ssim_map = jnp.mean(_ssim_terms(image, reference), axis=-1)
  centres = mask[half:mask.shape[0] - half, half:mask.shape[1] - half]
  kept = jnp.sum(centres)
  # max: no 0/0 where no window centre is kept (the result is then NaN, said so).
  return jnp.where(kept > 0, jnp.sum(ssim_map * centres) / jnp.maximum(kept, 1.0), jnp.nan)


def ssim_map(image, reference):
  """float32 [H - 10, W - 10]: the SSIM of each valid 11×11 window of images float32 [H, W, 3],
  the mean over channels; position (i, j) is the window centred on pixel (i + 5, j + 5)."""
  return jnp.mean(_ssim_terms(jnp.asarray(image, jnp.float32),
                              jnp.asarray(reference, jnp.float32)), axis=-1)


def ssim(image, reference, mask=None):
  """SSIM (11×11 Gaussian window, sigma 1.5, no padding) per image: float32 [...]; with mask
  (float32 [..., H, W]) the mean of `ssim_map` over the windows centred on kept pixels (NaN for
  an image with none)."""
  image, reference = jnp.asarray(image, jnp.float32), jnp.asarray(reference, jnp.float32)
  batch = image.shape[:-3]
  flat = lambda a: a.reshape(-1, *a.shape[-3:])
  if mask is None:
    return jax.vmap(_ssim_single)(flat(image), flat(reference)).reshape(batch)
  mask = jnp.broadcast_to(jnp.asarray(mask, jnp.float32), image.shape[:-1]).reshape(
      -1, *image.shape[-3:-1])
  return jax.vmap(_masked_ssim_single)(flat(image), flat(reference), mask).reshape(batch)
