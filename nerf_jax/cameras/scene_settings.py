"""How rays see the scene: config.data's box, bounds and spacing (the rest of config.data:
data/data_settings.DataSettings). Declared here, below the parts that read them (cameras, fields,
samplers, train, evaluate, run/), so each takes its defaults from this one place;
run/schema.py builds config.data from it.
"""

import dataclasses


@dataclasses.dataclass(frozen=True)
class SceneSettings:
  """config.data's fields of how rays see the scene (the rest: data/data_settings.DataSettings)."""
  lindisp: bool = False  # sample linearly in inverse depth instead of depth
  ndc: bool = False  # forward-facing scenes: rays in normalized device coordinates, t in [0, 1]
  near: float = 0.0  # near bound override (0 = the dataset's, 2 for tiny_nerf)
  far: float = 0.0  # far bound override (0 = the dataset's, 6 for tiny_nerf)
  scene_bound: float = 0.0  # half-size of the box sampled (0 = none, -1 = found from the data)
  visual_hull: bool = False  # carve the masks' hull (opacity, a subject's masks): empty outside
  contraction: str = ""  # unbounded scene: 'linf' or 'l2' contracts the space beyond the box
  inner_fraction: float = 0.5  # unbounded scene: share of samples inside the box (the rest beyond)
  focus: bool = False  # move the world so that the point the cameras look at is the origin
  subject: str = ""  # 'auto': scale, move the world so the subject's box fills ±scene_bound ('' off)
  photo_bounds: bool = False  # sample each photo's rays within its own near/far (Dataset.bounds)
  photo_zoom: bool = False  # data.subject's masks: each photo's focal fitted to the masks' hull
  subject_box: tuple = ()  # data.subject='box': the subject's (x, y, z centre, x, y, z half-extent)
