"""The settings of the images and cameras loaded: config.data's fields that data/loaders.py's
`load_dataset` reads (also read there as loaders.DataSettings). Declared in a module of their
own, below the format readers (colmap.py, llff.py, nerfstudio.py, formats/blender.py) that
take their defaults from it.
"""

import dataclasses
from typing import Any


@dataclasses.dataclass(frozen=True)
class DataSettings:
  """What `load_dataset` loads: config.data's fields of the images and cameras (the rest of
  config.data, how rays see the scene, is cameras/scene_settings.SceneSettings)."""
  path: str = ""  # dataset: .npz, Blender, LLFF, transforms.json or COLMAP folder; '' = built-in
  scene: str = "diffuse"  # built-in scene name (data/scenes)
  num_views: int = 100  # built-in scene: number of rendered views
  image_size: int = 100  # built-in scene: height = width in pixels
  holdout_from: int = -1  # views[holdout_from:] are test views; -1 = the format's own split
  held_out_looks: str = "neutral"  # per-photo-look scenes: test views 'neutral' or 'own' looks
  pixel_center: float = -1.0  # -1 = the data's own (0.5 centres; 0 corners for tiny_nerf .npz)
  background: Any = "auto"  # 'auto' (white for Blender data, else black), 'black', 'white' or RGB
  half_res: bool = False  # Blender data: load at half resolution
  factor: int = 1  # LLFF, transforms.json and COLMAP data: downsample images by this factor
  bd_factor: float = 0.75  # LLFF data: scale so the nearest bound is 1/bd_factor (0 = keep units)
  recenter: bool = True  # LLFF data: move the mean camera pose to the origin
  min_sharpness: float = 0.0  # transforms.json: drop frames < this x neighbours' sharpness (0 = off)
  without: str = ""  # built-in scene: capture effects left out, e.g. 'zoom,distortion' (the truth)
