"""Image quality metrics. Images are float32 [..., H, W, 3] in [0, 1]."""

import jax
import jax.numpy as jnp

from nerf_jax.backend import precision


def mse_to_psnr(mse):
  """PSNR in dB for a peak of 1; mse clamped at 1e-10 so a perfect match gives 100 dB, not inf."""
  return -10.0 * jnp.log10(jnp.maximum(mse, 1e-10))


def psnr(image, reference):
  """PSNR per image: float32 [...] from images float32 [..., H, W, C]."""
  return mse_to_psnr(jnp.mean((image - reference) ** 2, axis=(-3, -2, -1)))


def _gaussian_kernel(size=11, sigma=1.5):
  x = jnp.arange(size, dtype=jnp.float32) - (size - 1) / 2
  k = jnp.exp(-0.5 * (x / sigma) ** 2)
  return k / jnp.sum(k)


def _blur(x, kernel):
  """'Valid' separable filtering of x: float32 [H, W, C] with kernel: float32 [K]."""
  conv = lambda v: precision.convolve(v, kernel, mode="valid")  # full float32: a metric
  x = jax.vmap(jax.vmap(conv, in_axes=1, out_axes=1), in_axes=2, out_axes=2)(x)  # along H
  return jax.vmap(jax.vmap(conv, in_axes=0, out_axes=0), in_axes=2, out_axes=2)(x)  # along W


@jax.jit
def _ssim_single(image, reference):
  c1, c2 = 0.01 ** 2, 0.03 ** 2  # Wang et al. (2004) constants for a dynamic range of 1
  k = _gaussian_kernel()
  mu_x, mu_y = _blur(image, k), _blur(reference, k)
  var_x = _blur(image * image, k) - mu_x ** 2
  var_y = _blur(reference * reference, k) - mu_y ** 2
  cov = _blur(image * reference, k) - mu_x * mu_y
  num = (2 * mu_x * mu_y + c1) * (2 * cov + c2)
  den = (mu_x ** 2 + mu_y ** 2 + c1) * (var_x + var_y + c2)
  return jnp.mean(num / den)  # den >= c1·c2 > 0


def ssim(image, reference):
  """SSIM (11×11 Gaussian window, sigma 1.5, no padding) per image: float32 [...]."""
  image, reference = jnp.asarray(image, jnp.float32), jnp.asarray(reference, jnp.float32)
  batch = image.shape[:-3]
  flat = lambda a: a.reshape(-1, *a.shape[-3:])
  return jax.vmap(_ssim_single)(flat(image), flat(reference)).reshape(batch)
