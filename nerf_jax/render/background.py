"""Backgrounds: the one table of named colours, and swapping an image's background.

`config.data.background` is 'black', 'white' or an RGB triple in [0, 1]: the colour the model
renders and is scored on. Training on a fresh random colour per ray (so the field cannot paint
the background into its density: no floaters) is `config.train.random_background` on data with
opacity; data.background='random', its old spelling, is read as black + that switch
(config_lib.upgrade).
"""

import numpy as np

NAMED = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0)}


def parse(value, where="config.data.background"):
  """float32 [3] for a background name or RGB triple; ValueError naming `where` otherwise."""
  if isinstance(value, str):
    if value not in NAMED:
      raise ValueError(f"{where}: unknown name {value!r} (valid: black, white or an RGB "
                       "triple)")
    return np.array(NAMED[value], np.float32)
  try:
    rgb = np.asarray(value, np.float64)
  except (TypeError, ValueError):
    rgb = np.zeros(0)
  if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 1)):
    raise ValueError(f"{where}: expected an RGB triple in [0, 1], got {value!r}")
  return rgb.astype(np.float32)


def trains_on_random(random_background, has_opacity):
  """Whether training composites each ray on a fresh random colour: the switch
  `random_background` (train.random_background) on data with per-pixel opacity (RGBA, built-in
  scenes; without opacity the target cannot be moved to another background, so the switch does
  nothing)."""
  return bool(random_background and has_opacity)


def recomposite(rgb, acc, old, new):
  """Colours composited on `old` moved onto `new`: rgb + (1 - acc)·(new - old).

  rgb: float32 [..., 3], composited on `old` (float32 broadcastable to [..., 3]). acc: float32
  [...], opacity. new: float32 broadcastable to [..., 3]. Exact for any opacity: the field's
  emission is untouched, only the light let through, (1 - acc), sees the other background.
  Works on numpy and jax arrays alike.
  """
  return rgb + (1.0 - acc)[..., None] * (new - old)


def images_on_background(dataset, new):
  """(acc float32 [N, H, W], rgb float32 [N, H, W, 3]): the dataset's images re-composited on
  the background `new` (float32 [3], see `parse`), what the model is trained and scored
  against.

  With known opacity the background is swapped exactly (background.recomposite); without it
  the images are used as they are (acc = ones). Images of different sizes (a list,
  `Dataset.images`) give lists of [H_i, W_i] and [H_i, W_i, 3] arrays.
  """
  if isinstance(dataset.images, list):
    if dataset.accs is None:
      return [np.ones(a.shape[:-1], np.float32) for a in dataset.images], dataset.images
    old = np.asarray(dataset.background, np.float32)
    return dataset.accs, [recomposite(rgb, acc, old, new).astype(np.float32)
                          for rgb, acc in zip(dataset.images, dataset.accs)]
  if dataset.accs is None:
    return np.ones(dataset.images.shape[:-1], np.float32), dataset.images
  old = np.asarray(dataset.background, np.float32)
  return dataset.accs, recomposite(dataset.images, dataset.accs, old, new).astype(np.float32)
