"""What the viewer draws: a model, its parameters and its cameras, from a checkpoint or a run.

This module is the viewer's one contact with the rest of nerf_jax (restoring, ray generation,
image rendering, colour maps); re-point it here when those move.
"""

import dataclasses
import os

import jax
import numpy as np

from nerf_jax.cameras import rays
from nerf_jax.evaluate import visuals
from nerf_jax.render import background, image_renderer
from nerf_jax.run import experiment
from nerf_jax.viewer import camera, policy

colorize, to_uint8 = visuals.colorize, visuals.to_uint8

# One chunk of pixels' rays; compiled once for every frame size (rays.camera_rays's eager
# operations would compile for each new size, ~0.5 s).
_pixel_rays = jax.jit(rays.pixel_rays,
                      static_argnames=("pixel_center", "use_ndc", "with_radii"))


@dataclasses.dataclass
class Scene:
  """A model ready to draw and the training cameras to show.

  make_draw: fn(variables) -> image_renderer.Draw, draw(rays, background) -> numpy dict
    rgb [n, 3], depth [n], acc [n].
  dataset: the training data.Dataset (its poses, images and intrinsics are the cameras shown).
  near, far: float bounds. background: float32 [3]. pixel_center: the rays' (resolved).
  with_radii: the rays carry their radii (a field of cones: Field.cones).
  """
  config: object
  make_draw: object
  dataset: object
  near: float
  far: float
  background: np.ndarray
  pixel_center: float = 0.5
  with_radii: bool = False

  poses = property(lambda self: np.asarray(self.dataset.poses, np.float32))  # [N, 4, 4] c2w
  images = property(lambda self: self.dataset.images)  # float32 [N, H, W, 3]
  intrinsics = property(lambda self: tuple(float(v) for v in self.dataset.intrinsics))
  height = property(lambda self: self.dataset.height)
  width = property(lambda self: self.dataset.width)
  scene_bound = property(lambda self: float(self.config.data.scene_bound))  # 0 = no box

  @property
  def chunk(self):
    """Rays per piece of a frame's rays (config.render.chunk; a device-sized 0: the fallback)."""
    return self.config.render.chunk or image_renderer.FALLBACK_CHUNK

  def fov(self):
    """Vertical field of view (radians) of the first training camera."""
    return camera.vertical_fov(self.height, self.intrinsics[1])

  def camera_views(self):
    """[(vertical fov in radians, width / height)] of each training image's own camera
    (Dataset.cameras: images of several sizes or focal lengths each keep theirs)."""
    cams = self.dataset.cameras
    return [(camera.vertical_fov(int(h), float(fy)), float(w) / float(h))
            for h, w, fy in zip(cams.height, cams.width, cams.fy)]

  def frame_rays(self, c2w, height, width, fov):
    """rays.Rays [height, width] (numpy) of camera `c2w` float [4, 4] with vertical `fov`
    (radians), as rays.camera_rays makes them, one chunk of pixels at a time."""
    intrinsics = camera.frame_intrinsics(height, width, fov)
    num, chunk = height * width, self.chunk
    rows, columns = np.divmod(np.arange(-(-num // chunk) * chunk), width)
    rows, columns = rows.astype(np.float32), columns.astype(np.float32)
    pieces = [jax.tree_util.tree_map(np.asarray, _pixel_rays(
        columns[i:i + chunk], rows[i:i + chunk], height, width, intrinsics, c2w, self.near,
        self.far, pixel_center=self.pixel_center, use_ndc=self.config.data.ndc,
        with_radii=self.with_radii))
              for i in range(0, len(rows), chunk)]
    return jax.tree_util.tree_map(
        lambda *a: np.concatenate(a)[:num].reshape(height, width, *a[0].shape[1:]), *pieces)

  def compile_steps(self, draw):
    """image_renderer.Draw.compile_steps of `draw`, after compiling the frame rays (yielding 0:
    no frame is ready yet)."""
    self.frame_rays(np.eye(4, dtype=np.float32), 1, 1, self.fov())
    yield 0
    yield from draw.compile_steps()

  def render(self, draw, c2w, height, width, fov, cancelled=None):
    """Render a `height`×`width` frame of camera `c2w` float [4, 4] with vertical `fov`
    (radians), in chunks (see policy.render_in_chunks). Returns numpy dict rgb [H, W, 3],
    depth [H, W], acc [H, W], or None when `cancelled()` turned true."""
    chunk = getattr(draw, "chunk", self.chunk)  # the rays each call of `draw` is padded to
    return policy.render_in_chunks(draw, self.frame_rays(c2w, height, width, fov), chunk,
                                   self.background, cancelled)


def from_run(exp):
  """The Scene of a model being trained (or restored): an experiment_parts.Experiment."""
  config = exp.config
  return Scene(config=config, make_draw=image_renderer.make_image_renderer(exp.renderer, exp.image),
               dataset=exp.train_ds, near=float(exp.near), far=float(exp.far),
               background=background.parse(config.data.background),
               pixel_center=exp.pixel_center, with_radii=exp.renderer.field.cones)


def from_workdir(workdir):
  """(Scene, variables, step) of the newest checkpoint in `workdir` (variables: renderer.py).

  Raises FileNotFoundError or experiment.TrainingError (one line) when there is none.
  """
  if not os.path.isdir(workdir):
    raise FileNotFoundError(f"--workdir={workdir}: no such directory")
  exp, state = experiment.restore(workdir)
  return from_run(exp), state.variables, int(state.step)
