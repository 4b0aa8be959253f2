"""The built-in scenes (data.path ''): rendered on the spot by data/scenes."""

from nerf_jax.data import formats, scenes
from nerf_jax.data.dataset import DataError


def detect(path):
  """Whether data.path names no data: the built-in scene data.scene is trained."""
  return not path


def load(path, background, settings):
  """(train, test) of the built-in scene settings.scene (data_settings.DataSettings): image_size,
  num_views and pixel_center apply (-1 = 0.5); focal keeps tiny_nerf's field of view;
  holdout_from -1 is the reference's 80/20 split; held_out_looks 'own' gives the test views of
  a scene with per-photo looks their own (scenes/photos.py); `without` leaves capture effects
  out. `path` ('') and `background` (the scene draws its own) are unused."""
  del path, background
  name, size = settings.scene, settings.image_size
  if name not in scenes.SCENES:
    raise DataError(f"data.scene: unknown scene {name!r} (valid: {', '.join(scenes.SCENES)})")
  try:
    effects, lens_parts = scenes.without(scenes.get_scene(name).effects, settings.without)
  except ValueError as error:
    raise DataError(str(error)) from None
  dataset = scenes.make_dataset(
      name, num_views=settings.num_views, height=size, width=size,
      focal=scenes.TINY_NERF_FOCAL * size / 100,
      pixel_center=0.5 if settings.pixel_center == -1 else settings.pixel_center)
  train, test = dataset.split(settings.holdout_from)
  if settings.held_out_looks not in ("neutral", "own"):
    raise DataError(f"data.held_out_looks={settings.held_out_looks!r}: use 'neutral' or 'own'")
  if settings.held_out_looks == "own":
    test = scenes.held_out_with_own_looks(test, effects, len(train))
  return scenes.photographed(train, effects, lens_parts=lens_parts), test


FORMAT = formats.Format("scene", detect, load)
