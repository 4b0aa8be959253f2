"""Dataset loading: the settings of the images and cameras loaded (`DataSettings`, declared in
data/data_settings.py below the format readers, which take their defaults from it) and
`load_dataset`, which reads data.path in the format it detects (data/formats/: built-in
scenes, tiny_nerf .npz, nerfstudio's transforms.json, mip-NeRF multiscale, NeRF-synthetic
(Blender), LLFF and COLMAP folders).

Every malformed input raises `DataError` with a one-line message naming the file and field.
Every loader fills `Dataset.accs` and `Dataset.background` where the input tells them: RGBA
images give the opacity (alpha) and are composited on the `background` argument.
"""

import os

from nerf_jax.data import formats
# The settings, also read through this module (run/schema.py, the tests).
from nerf_jax.data.data_settings import DataSettings  # pylint: disable=unused-import
from nerf_jax.data.dataset import DataError
# The .npz and Blender readers, also read through this module (nerf_jax.data, the tests).
from nerf_jax.data.formats.blender import load_blender  # pylint: disable=unused-import
from nerf_jax.data.formats.npz import load_npz  # pylint: disable=unused-import
from nerf_jax.data.validate import parse_background


def auto_background(path):
  """(name, why): the background data.background='auto' means for the data at `path` ('' = a
  built-in scene), the convention of its family (its format's rule, data/formats/): 'white'
  for a Blender (NeRF-synthetic) folder of RGBA images (transforms_train.json; the first
  frame's image decides) and for a mip-NeRF multiscale folder of RGBA images (metadata.json,
  made from Blender's; the first training image decides), on which every published table
  scores that data; 'black' for everything else (built-in scenes, .npz, LLFF, transforms.json
  and COLMAP folders, Blender and multiscale folders of RGB images)."""
  return formats.auto_background(path)


def is_auto(background):
  """Whether a data.background value is 'auto' (resolved from the data: `auto_background`)."""
  return isinstance(background, str) and background == "auto"


def load_dataset(settings):
  """(train, test) Datasets as `settings` (DataSettings) say, read by the first format of
  data/formats' FORMATS that detects settings.path (DataError naming what each expects if none
  does).

  path '' = the built-in `scene` (image_size, num_views and pixel_center apply, -1 = 0.5; focal
  keeps tiny_nerf's field of view; held_out_looks 'own' gives the test views of a scene with
  per-photo looks their own, scenes/photos.py); background ('auto': `auto_background`) and
  half_res apply to .npz and Blender; factor, bd_factor (0 = keep the file's units) and
  recenter to LLFF, see `load_llff`: the defaults are the original NeRF's LLFF pipeline, which
  NDC rays (near plane 1, world -z forward) rely on.
  holdout_from: views[holdout_from:] are the test views; -1 = the default split of the format:
  the reference's 80/20 for built-in scenes and .npz, every 8th view (0, 8, 16, ...) for LLFF
  (the original NeRF's convention), for COLMAP folders (`colmap.load_split`) and for
  transforms.json folders unless the file names its test images (`nerfstudio.load_split`);
  Blender folders and mip-NeRF's multiscale folders (metadata.json, `multicam.load`:
  per-image cameras) have their own test split and ignore it.
  factor also downscales transforms.json folders (nerfstudio / nerf-process output) and COLMAP
  folders (images/ and sparse/0/, `colmap.load`), and min_sharpness drops transforms.json's
  blurry frames. A folder with poses_bounds.npy is read as LLFF even with a COLMAP model beside
  it (LLFF's own data has both).
  """
  path = settings.path
  background = parse_background(auto_background(path)[0] if is_auto(settings.background)
                                else settings.background)
  if path and not os.path.exists(path):
    raise DataError(f"{path}: no such file or directory")
  record = formats.detect(path)
  if record is None:
    raise DataError(formats.unknown(path))
  return record.load(path, background, settings)
