"""Rendering trained models: test-view evaluation, 360° videos, views from a pose file.

Depth images are z-depth (distance along the camera's optical axis, see rays.py); the float
arrays are saved as `.npy` (float32, scene units; a ray that hits nothing has depth = far), and
the PNGs map [near, far] to a colour map. With NDC rays (forward-facing data) depth is the NDC
ray parameter in [0, 1] instead.
"""

import json
import os
import warnings

import imageio.v2 as imageio
import numpy as np

from nerf_jax import metrics, progress, renderer
from nerf_jax.rays import orbit_poses, spiral_poses

# Control points of a perceptually ordered colour map (dark blue -> teal -> yellow), for depth.
_CMAP = np.array([[0.05, 0.03, 0.25], [0.23, 0.30, 0.55], [0.13, 0.57, 0.55],
                  [0.37, 0.79, 0.38], [0.99, 0.91, 0.14]])


def colorize(depth, near, far):
  """Colour-mapped depth: uint8 [..., 3] from depth float32 [...] (near = dark, far = bright)."""
  x = np.clip((np.asarray(depth) - near) / max(far - near, 1e-9), 0.0, 1.0)
  pos = np.linspace(0.0, 1.0, len(_CMAP))
  rgb = np.stack([np.interp(x, pos, _CMAP[:, c]) for c in range(3)], axis=-1)
  return to_uint8(rgb)


def to_uint8(image):
  """uint8 image from a float image in [0, 1]."""
  return (np.clip(np.asarray(image), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def background_colour(config):
  """The compositing background as float32 [3] (black for 'random', which is drawn per ray)."""
  bg = config.data.background
  named = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0), "random": (0.0, 0.0, 0.0)}
  if isinstance(bg, str):
    if bg not in named:
      raise ValueError(f"config.data.background={bg!r}: use 'black', 'white', 'random' "
                          "or an RGB triple")
    return np.array(named[bg], np.float32)
  return np.asarray(bg, np.float32).reshape(3)


def images_on_background(dataset, config):
  """(acc float32 [N, H, W], rgb float32 [N, H, W, 3]): the dataset's images re-composited on
  the configured background (`background_colour`), what the model is trained and scored against.

  With known opacity, `images + (1 - acc)·(new - old)` swaps the background exactly; without it
  the images are used as they are (acc = ones).
  """
  accs = getattr(dataset, "accs", None)
  if accs is None:
    return np.ones(dataset.images.shape[:-1], np.float32), dataset.images
  old = np.asarray(getattr(dataset, "background", (0.0, 0.0, 0.0)), np.float32)
  rgb = dataset.images + (1.0 - accs)[..., None] * (background_colour(config) - old)
  return accs, rgb.astype(np.float32)


def render_pose(draw, pose, height, width, intrinsics, config, background):
  """Render one camera with `draw` (see `renderer.make_image_renderer`): numpy dict
  rgb [H, W, 3], depth [H, W], acc [H, W]."""
  origins, directions, viewdirs = renderer.camera_rays(height, width, intrinsics, pose, config)
  return draw(origins, directions, viewdirs=viewdirs, background=background)


def make_evaluator(model, config, near, far, test_ds):
  """fn(params, max_views=None, out_dir=None, on_view=None) -> {'psnr', 'ssim', 'per_view'}.

  Evaluates the test views. With `out_dir`, writes per view a PNG of
  [prediction | depth | ground truth] and depth `.npy`. on_view(index, out, truth) is called
  for every view with the rendered numpy dict (rgb [H, W, 3], depth [H, W], acc [H, W]) and the
  true image float32 [H, W, 3] on the configured background (see `images_on_background`; the
  trainer sends the first one to TensorBoard).
  """
  image_renderer = renderer.make_image_renderer(model, config, near, far)
  background = background_colour(config)
  truths = images_on_background(test_ds, config)[1]

  def evaluate(params, max_views=None, out_dir=None, on_view=None):
    count = len(test_ds) if max_views is None else min(max_views, len(test_ds))
    per_view = []
    draw = image_renderer(params)
    for i in range(count):
      out = render_pose(draw, test_ds.poses[i], test_ds.height, test_ds.width,
                        test_ds.intrinsics, config, background)
      truth = truths[i]
      view = {"view": i, "psnr": float(metrics.psnr(out["rgb"], truth)),
              "ssim": float(metrics.ssim(out["rgb"], truth))}
      per_view.append(view)
      if on_view is not None:
        on_view(i, out, truth)
      if out_dir:
        _write_eval_view(out_dir, i, out, truth, near, far)
    result = {"psnr": float(np.mean([v["psnr"] for v in per_view])),
              "ssim": float(np.mean([v["ssim"] for v in per_view])), "per_view": per_view}
    if out_dir:
      with open(os.path.join(out_dir, "metrics.json"), "w") as f:
        json.dump(result, f, indent=2)
    return result

  return evaluate


def _write_eval_view(out_dir, index, out, truth, near, far):
  os.makedirs(out_dir, exist_ok=True)
  panel = np.concatenate([to_uint8(out["rgb"]), colorize(out["depth"], near, far),
                          to_uint8(truth)], axis=1)
  imageio.imwrite(os.path.join(out_dir, f"view_{index:03d}.png"), panel)
  np.save(os.path.join(out_dir, f"depth_{index:03d}.npy"), out["depth"].astype(np.float32))


def scaled_camera(dataset, scale=1.0):
  """(height, width, intrinsics) of the dataset's camera with `scale` times as many pixels per side.

  The field of view stays the same: focal lengths and principal point scale with the image.
  """
  height, width = max(1, round(dataset.height * scale)), max(1, round(dataset.width * scale))
  sx, sy = width / dataset.width, height / dataset.height
  fx, fy, cx, cy = dataset.intrinsics
  return height, width, (fx * sx, fy * sy, cx * sx, cy * sy)


def render_frames(model, params, config, near, far, poses, height, width, intrinsics):
  """Render a list of poses: yields numpy dicts rgb [H, W, 3], depth [H, W], acc [H, W]."""
  draw = renderer.make_image_renderer(model, config, near, far)(params)
  background = background_colour(config)
  for pose in poses:
    yield render_pose(draw, pose, height, width, intrinsics, config, background)


def video_poses(config, dataset):
  """The camera path of the video: float32 [F, 4, 4].

  Forward-facing data (NDC): a spiral around the mean camera, focused at a depth between the
  bounds (weighted towards near, in disparity, as LLFF does). Otherwise: a 360° orbit, the
  reference's pose_spherical path.
  """
  frames = config.render.video_frames
  if not config.data.get("ndc", False):
    return orbit_poses(frames, config.render.orbit_phi, config.render.orbit_radius)
  centre = np.eye(4, dtype=np.float32)
  centre[:3, :] = dataset.poses[:, :3, :].mean(axis=0)
  u, _, vt = np.linalg.svd(centre[:3, :3])
  centre[:3, :3] = u @ vt  # the nearest rotation to the mean rotation
  radii = np.percentile(np.abs(dataset.poses[:, :3, 3] - centre[:3, 3]), 90, axis=0)
  focus = 1.0 / (0.25 / dataset.near + 0.75 / dataset.far)
  return spiral_poses(centre, np.maximum(radii, 1e-3), focus, frames)


def render_video(model, params, config, near, far, dataset, out_dir, depth_npy=False,
                 show_progress=True, scale=1.0):
  """The video path (see `video_poses`) as rgb.mp4 and depth.mp4 in `out_dir`.

  depth_npy: also save the float depth of every frame as `depth_frames.npy`, float32 [F, H, W]
  (z-depth in scene units, see the module docstring). scale: frames have `scale` times the
  dataset's pixels per side (see `scaled_camera`). Returns {'rgb', 'depth'[, 'depth_npy']} paths.
  """
  os.makedirs(out_dir, exist_ok=True)
  poses = video_poses(config, dataset)
  rgb_frames, depth_frames, depths = [], [], []
  frames = render_frames(model, params, config, near, far, poses,
                         *scaled_camera(dataset, scale))
  if show_progress:
    frames = progress.track(frames, total=len(poses), desc="video")
  for out in frames:
    rgb_frames.append(to_uint8(out["rgb"]))
    depth_frames.append(colorize(out["depth"], near, far))
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
      imageio.mimwrite(paths[name], frames, fps=config.render.fps, macro_block_size=1)
  return paths


def load_poses(path):
  """Camera poses float32 [N, 4, 4] from a .npy ([N,3,4] or [N,4,4]) or a Blender-style .json."""
  if path.endswith(".json"):
    with open(path) as f:
      poses = np.array([frame["transform_matrix"] for frame in json.load(f)["frames"]])
  else:
    poses = np.load(path)
  poses = np.asarray(poses, np.float32)
  if poses.ndim != 3 or poses.shape[1:] not in ((3, 4), (4, 4)):
    raise ValueError(f"{path}: poses must have shape [N, 3, 4] or [N, 4, 4], got {poses.shape}")
  if poses.shape[1] == 3:
    bottom = np.broadcast_to(np.array([0, 0, 0, 1], np.float32), (len(poses), 1, 4))
    poses = np.concatenate([poses, bottom], axis=1)
  return poses


def render_views(model, params, config, near, far, dataset, poses, out_dir, scale=1.0):
  """Render `poses` to `out_dir/view_XXX.png` (+ depth PNG and .npy). Returns the count.

  scale: images have `scale` times the dataset's pixels per side (see `scaled_camera`).
  """
  os.makedirs(out_dir, exist_ok=True)
  frames = render_frames(model, params, config, near, far, poses,
                         *scaled_camera(dataset, scale))
  for i, out in enumerate(frames):
    imageio.imwrite(os.path.join(out_dir, f"view_{i:03d}.png"), to_uint8(out["rgb"]))
    imageio.imwrite(os.path.join(out_dir, f"depth_{i:03d}.png"), colorize(out["depth"], near, far))
    np.save(os.path.join(out_dir, f"depth_{i:03d}.npy"), out["depth"].astype(np.float32))
  return len(poses)
