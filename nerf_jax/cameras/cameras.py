"""Per-image pinhole cameras: each image's size and intrinsics (nerfstudio's `Cameras`).

A `Cameras` holds N cameras as arrays, one entry per image; `camera(i)` gives one camera in the
form the ray functions take (`rays.camera_rays(height, width, intrinsics, ...)`), `table()`
the per-ray form (`rays.pixel_rays` broadcasts intrinsics arrays over the rays).
"""

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class Cameras:
  """N pinhole cameras (conventions of `nerf_jax.cameras.rays`).

  fx, fy: float64 [N], focal lengths in pixels. cx, cy: float64 [N], principal point in pixels.
  width, height: int64 [N], image size in pixels.
  """
  fx: np.ndarray
  fy: np.ndarray
  cx: np.ndarray
  cy: np.ndarray
  width: np.ndarray
  height: np.ndarray

  def __post_init__(self):
    for name in ("fx", "fy", "cx", "cy"):
      object.__setattr__(self, name, np.asarray(getattr(self, name), np.float64).reshape(-1))
    for name in ("width", "height"):
      object.__setattr__(self, name, np.asarray(getattr(self, name), np.int64).reshape(-1))
    sizes = {len(getattr(self, f.name)) for f in dataclasses.fields(self)}
    if len(sizes) != 1:
      raise ValueError(f"Cameras: fields of different lengths {sorted(sizes)}")

  @classmethod
  def shared(cls, num, height, width, intrinsics):
    """`num` copies of one camera: height, width int, intrinsics (fx, fy, cx, cy)."""
    fx, fy, cx, cy = (np.full(num, float(v)) for v in intrinsics)
    return cls(fx, fy, cx, cy, np.full(num, int(width)), np.full(num, int(height)))

  @classmethod
  def stack(cls, cameras):
    """One Cameras of the cameras in the list `cameras` (each (height, width, (fx, fy, cx,
    cy)), `camera`'s form)."""
    cams = list(cameras)
    column = lambda k: np.array([c[2][k] for c in cams], np.float64)
    return cls(column(0), column(1), column(2), column(3), [c[1] for c in cams],
               [c[0] for c in cams])

  def __len__(self):
    return len(self.fx)

  def camera(self, index):
    """(height, width, (fx, fy, cx, cy)) of camera `index`, as Python int and float."""
    return (int(self.height[index]), int(self.width[index]),
            (float(self.fx[index]), float(self.fy[index]), float(self.cx[index]),
             float(self.cy[index])))

  def subset(self, indices):
    """The cameras `indices` (int array, slice or list)."""
    return Cameras(**{f.name: getattr(self, f.name)[indices] for f in dataclasses.fields(self)})

  def is_shared(self):
    """Whether every camera is the same (size and intrinsics)."""
    return all(np.all(getattr(self, f.name) == getattr(self, f.name)[0])
               for f in dataclasses.fields(self))

  def same_size(self):
    """Whether every image has the same height and width."""
    return bool(np.all(self.width == self.width[0]) and np.all(self.height == self.height[0]))

  def num_pixels(self):
    """int64 [N], height · width of each camera."""
    return self.height * self.width

  def table(self):
    """float32 [N, 4]: (fx, fy, cx, cy) of each camera, for per-ray intrinsics."""
    return np.stack([self.fx, self.fy, self.cx, self.cy], -1).astype(np.float32)
