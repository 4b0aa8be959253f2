"""What render.py writes from a trained model: videos, views from a pose file, the surface mesh,
and the render command (test-view evaluation is evaluation.py, camera paths camera_paths.py).

Depth images are z-depth (distance along the camera's optical axis, see rays.py); the float
arrays are saved as `.npy` (float32, scene units; a ray that hits nothing has depth = far), and
the PNGs map [near, far] to a colour map. With NDC rays (forward-facing data) depth is the NDC
ray parameter in [0, 1] instead.
"""

import importlib.util
import math
import os
import warnings

import imageio.v2 as imageio
import numpy as np

from nerf_jax.cameras import camera_paths
from nerf_jax.evaluate import evaluation, lpips, visuals
from nerf_jax.render import background, image_renderer, surface
from nerf_jax.run import builders, experiment
from nerf_jax.train import progress


def render_frames(exp, variables, poses, scale=1.0, cameras=None):
  """Render `poses` (float32 [F, 4, 4]) through the training camera with `scale` times its pixels
  per side, or frame i through `cameras[i]` (height, width, intrinsics; see `frame_cameras`):
  yields numpy dicts rgb [H, W, 3], depth [H, W], acc [H, W]."""
  draw = image_renderer.make_image_renderer(exp.renderer, exp.image)(variables)
  bg = background.parse(exp.config.data.background)
  shared = exp.camera(scale)
  for i, pose in enumerate(poses):
    yield draw(exp.rays(pose, shared if cameras is None else cameras[i]), bg)


def frame_cameras(exp, poses, scale=1.0):
  """Each frame's camera (height, width, intrinsics) for `poses` float32 [F, 4, 4] where the
  training images have cameras of their own (a collection shot at several zooms), else None.

  Every frame keeps the training camera's size with `scale` (a video's frames share one size)
  and its principal point, and takes the vertical field of view and pixel aspect of the
  training image whose camera centre is nearest the frame's, so a path through the capture
  sees what each photo saw. Images of one field of view at several sizes (multiscale data)
  give the training camera (exactly where the sizes divide evenly)."""
  ds = exp.train_ds
  if ds.image_cameras is None:
    return None
  height, width, (_, _, cx, cy) = exp.camera(scale)
  centres = np.asarray(ds.poses, np.float64)[:, :3, 3]
  frames = np.asarray(poses, np.float64)[:, :3, 3]
  nearest = np.argmin(np.linalg.norm(frames[:, None] - centres[None], axis=-1), axis=1)
  cameras = []
  for k in nearest:
    image_height, _, (fx, fy, _, _) = ds.cameras.camera(int(k))
    zoom = height / image_height  # image k's field of view spread over the frame's height
    cameras.append((height, width, (fx * zoom, fy * zoom, cx, cy)))
  return cameras


def follows_trajectory(exp):
  """Whether the video follows the capture's own path (render.video_path; 'auto': for
  unbounded scenes and transforms.json captures, whose data found its own box, where an orbit
  about the origin could fly through walls) instead of an orbit or a spiral."""
  kind = exp.config.render.video_path
  if kind not in ("auto", "orbit", "trajectory"):
    raise ValueError(f"config.render.video_path={kind!r}: use 'auto', 'orbit' or 'trajectory'")
  if kind == "auto":
    return bool(exp.config.data.contraction or exp.train_ds.aabb is not None)
  return kind == "trajectory"


def video_writer_missing():
  """Why no mp4 can be written here (one line naming the install command), or None."""
  if importlib.util.find_spec("imageio_ffmpeg") is None:
    return "no mp4 writer: imageio-ffmpeg is not installed (pip install imageio-ffmpeg)"
  return None


LONG_FINAL_SECONDS = 120.0  # a final evaluation + video expected to last longer says so first


def final_render_seconds(test_pixels, video_frames, frame_pixels, rays_per_second):
  """Seconds the final evaluation and video are expected to take: every ray of the test views
  scored (test_pixels: int, their pixels) and of the video's frames (video_frames frames of
  frame_pixels pixels each) at the training's measured rate (rays_per_second: rays a second
  through a training step). A training step's ray costs a backward pass a render does not
  pay, a render's ray render.num_samples (and the fine samples) that training may not: a rough
  guide, not a promise."""
  return (test_pixels + video_frames * frame_pixels) / max(rays_per_second, 1e-9)


def final_render_line(exp, rays_per_second, long_seconds=None):
  """One line announcing a final evaluation (+ video) expected to last more than long_seconds
  (None = LONG_FINAL_SECONDS), with the flags that shorten it; None when it is expected to be
  short or the rate is unknown. exp: experiment_parts.Experiment; rays_per_second: the
  training's last measured rate."""
  if not rays_per_second:
    return None
  long_seconds = LONG_FINAL_SECONDS if long_seconds is None else long_seconds
  config, test_ds = exp.config, exp.test_ds
  views = evaluation.scored_views(len(test_ds), config.eval.test_every, labels=test_ds.labels)
  fit = fit_rays(config, len(views))
  test_pixels = int(sum(test_ds.cameras.num_pixels()[views])) + round(FIT_RAY_COST * fit)
  frames = config.render.video_frames if (config.render.after_training and
                                          video_writer_missing() is None) else 0
  height, width, _ = exp.camera()
  seconds = final_render_seconds(test_pixels, frames, height * width, rays_per_second)
  if seconds <= long_seconds:
    return None
  every = max(2, math.ceil(config.eval.test_every * seconds / max(long_seconds, 1e-9)))
  video = f" and a {frames}-frame video" if frames else ""
  shorten = f"--config.eval.test_every={every} (test views 0, {every}, {2 * every}, ...)" + (
      " and --config.render.video_frames=0 (no video)" if frames else "") + (
      " or --config.eval.fit_steps=100 (a tenth of the codes' fit)" if fit else "")
  fitted = f" and fit their codes ({fit:,} rays)" if fit else ""
  return (f"final evaluation: about {_duration(seconds)} to render {len(views)} test views"
          f"{fitted}{video} ({test_pixels + frames * height * width:,} rays' worth at "
          f"training's {rays_per_second:,.0f} rays/s); to shorten it: {shorten}")


# A ray of the held-out codes' fit costs about a sixth of a training ray (landmark, auto's
# config at 100 px on one core: 20 views x 1000 x 1024 fit rays took 14 min, training ran
# 4,100 rays/s): the field is frozen, so no parameter gradient is formed.
FIT_RAY_COST = 1 / 6


def fit_rays(config, num_views):
  """Rays the held-out codes' fit renders for `num_views` scored views (eval.appearance=
  'left_half' with appearance codes: eval.fit_steps x eval.fit_rays each), else 0."""
  if config.eval.appearance != "left_half" or config.model.appearance_dims <= 0:
    return 0
  return num_views * config.eval.fit_steps * config.eval.fit_rays


def _duration(seconds):
  """'45 s', '12 min' or '2.5 h'."""
  if seconds < 90:
    return f"{seconds:.0f} s"
  return f"{seconds / 60:.0f} min" if seconds < 5400 else f"{seconds / 3600:.1f} h"


def render_video(exp, variables, out_dir, depth_npy=False, show_progress=True, scale=1.0,
                 poses=None):
  """A video as rgb.mp4 and depth.mp4 in `out_dir`: of `poses` (float32 [F, 4, 4]) through the
  training camera, or of the default path (see `camera_paths.video_poses`), each frame with the
  field of view of its nearest training image where the images have their own (`frame_cameras`).

  depth_npy: also save the float depth of every frame as `depth_frames.npy`, float32 [F, H, W]
  (z-depth in scene units, see the module docstring). scale: frames have `scale` times the
  training images' pixels per side (see Experiment.camera). Returns the paths:
  {'rgb', 'depth'[, 'depth_npy']}. FileNotFoundError (one line) without an mp4 writer.
  """
  missing = video_writer_missing()
  if missing:
    raise FileNotFoundError(missing)
  os.makedirs(out_dir, exist_ok=True)
  rc = exp.config.render
  default_path = poses is None
  if default_path:
    poses = camera_paths.video_poses(exp.train_ds, rc.video_frames, exp.config.data.ndc,
                                     rc.orbit_phi, rc.orbit_radius,
                                     trajectory=follows_trajectory(exp))
  near, far = exp.near, exp.far
  rgb_frames, depth_frames, depths = [], [], []
  cameras = frame_cameras(exp, poses, scale) if default_path else None
  frames = render_frames(exp, variables, poses, scale, cameras)
  if show_progress:
    frames = progress.track(frames, total=len(poses), desc="video")
  for out in frames:
    rgb_frames.append(visuals.to_uint8(out["rgb"]))
    depth_frames.append(visuals.colorize(out["depth"], near, far))
    if depth_npy:
      depths.append(out["depth"].astype(np.float32))
  paths = {}
  if depth_npy:
    paths["depth_npy"] = os.path.join(out_dir, "depth_frames.npy")
    np.save(paths["depth_npy"], np.stack(depths))
  for name, frames in (("rgb", rgb_frames), ("depth", depth_frames)):
    paths[name] = os.path.join(out_dir, f"{name}.mp4")
    with warnings.catch_warnings():  # imageio-ffmpeg forks ffmpeg; JAX warns about any fork
      warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
      imageio.mimwrite(paths[name], frames, fps=exp.config.render.fps, macro_block_size=1)
  return paths


def render_views(exp, variables, poses, out_dir, scale=1.0):
  """Render `poses` to `out_dir/view_XXX.png` (+ depth PNG and .npy). Returns the count.

  scale: images have `scale` times the training images' pixels per side.
  """
  os.makedirs(out_dir, exist_ok=True)
  near, far = exp.near, exp.far
  for i, out in enumerate(render_frames(exp, variables, poses, scale)):
    imageio.imwrite(os.path.join(out_dir, f"view_{i:03d}.png"), visuals.to_uint8(out["rgb"]))
    imageio.imwrite(os.path.join(out_dir, f"depth_{i:03d}.png"),
                    visuals.colorize(out["depth"], near, far))
    np.save(os.path.join(out_dir, f"depth_{i:03d}.npy"), out["depth"].astype(np.float32))
  return len(poses)


MODES = ("eval", "video", "views", "path", "mesh")


def mesh_bound(config):
  """Half-size of the mesh export box: the scene box, else the grid's box, else 1.5 (the 360°
  built-in scenes fit in a ball of radius 1.2)."""
  if config.data.scene_bound > 0:
    return float(config.data.scene_bound)
  if config.model.encoding not in ("posenc", "ipe"):  # a lattice
    return float(config.model.grid_bound)
  return 1.5


def export_mesh(exp, variables, resolution=128, threshold=50.0, bound=0.0):
  """The coloured surface (surface.extract) of the final network of a trained `exp`; bound 0 =
  `mesh_bound`. ValueError for NDC runs."""
  if exp.config.data.ndc:
    raise ValueError("mesh export needs world-space rays: this run uses NDC (config.data.ndc), "
                     "whose density lives in a warped space")
  return surface.extract(exp.renderer.field, exp.renderer.final_params(variables),
                         bound or mesh_bound(exp.config), resolution, threshold)


def render(workdir, mode, poses_path="", out_dir="", depth_npy=False, resolution=128,
           threshold=50.0, bound=0.0, scale=1.0, path_frames=30, overrides=None):
  """Render `mode` (one of MODES) from the newest checkpoint of `workdir`; returns what it wrote.

  depth_npy: video mode also writes float depth_frames.npy. resolution, threshold, bound: mesh
  mode (see surface.extract). scale: video and views modes render `scale` times the training
  images' pixels per side. path_frames: path mode, frames from one key camera to the next.
  overrides: {dotted field: value} set on the run's saved config (render.py's --config.eval.*).
  """
  if not os.path.isdir(workdir):
    raise FileNotFoundError(f"--workdir={workdir}: no such directory")
  if scale <= 0:
    raise ValueError(f"--scale={scale}: must be positive")
  if mode in ("views", "path") and not poses_path:
    raise ValueError(f"--mode={mode} needs --poses=FILE (.npy [N,4,4] or .json with frames)")
  if mode in ("views", "path") and not os.path.exists(poses_path):
    raise FileNotFoundError(f"{poses_path}: no such poses file")
  exp, state = experiment.restore(workdir, overrides=overrides)
  variables = state.variables
  print(f"restored step {int(state.step)} from {workdir}", flush=True)
  out_dir = out_dir or os.path.join(workdir, mode)
  if mode == "mesh":
    mesh = export_mesh(exp, variables, resolution, threshold, bound)
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, "mesh.ply")
    surface.write_ply(path, mesh["vertices"], mesh["faces"], mesh["colors"])
    print(f"wrote {len(mesh['vertices'])} vertices and {len(mesh['faces'])} faces to {path}")
    return path
  if mode == "eval":
    result = builders.make_evaluator(exp)(variables, out_dir=out_dir)
    print(f"test PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.4f}, "
          f"{lpips.describe(result)} over {len(result['per_view'])} views -> {out_dir}")
    return result
  if mode in ("video", "path"):
    poses = camera_paths.path_poses(poses_path, path_frames) if mode == "path" else None
    paths = render_video(exp, variables, out_dir, depth_npy=depth_npy, scale=scale, poses=poses)
    print(f"wrote {', '.join(paths.values())}")
    return paths
  count = render_views(exp, variables, camera_paths.load_poses(poses_path), out_dir, scale)
  print(f"wrote {count} views to {out_dir}")
  return out_dir
