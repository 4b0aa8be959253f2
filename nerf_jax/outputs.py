"""What render.py writes from a trained model: test-view evaluation, videos, views from a pose
file, the surface mesh.

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

from nerf_jax import background, experiment, image_renderer, lpips, metrics, progress, surface
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


def images_on_background(dataset, config):
  """(acc float32 [N, H, W], rgb float32 [N, H, W, 3]): the dataset's images re-composited on
  the configured background, what the model is trained and scored against.

  With known opacity the background is swapped exactly (background.recomposite); without it
  the images are used as they are (acc = ones).
  """
  if dataset.accs is None:
    return np.ones(dataset.images.shape[:-1], np.float32), dataset.images
  old = np.asarray(dataset.background, np.float32)
  new = background.parse(config.data.background)
  return dataset.accs, background.recomposite(dataset.images, dataset.accs, old,
                                              new).astype(np.float32)


def make_evaluator(exp):
  """fn(variables, max_views=None, out_dir=None, on_view=None) -> {'psnr', 'ssim', 'lpips',
  'per_view'} (variables: a TrainState's, renderer.py); without LPIPS (the `lpips` extra missing, or images under 31 px a side) the
  'lpips' keys are absent and 'lpips_skipped' says why in one line. Where the data has true
  opacity (and depth) the view means of `geometry_errors` come too: 'empty_opacity',
  'floaters' (and 'depth_error').

  Evaluates the test views of `exp` (an experiment.Experiment). With `out_dir`, writes per view
  a PNG of [prediction | depth | ground truth] and depth `.npy`. on_view(index, out, truth) is
  called for every view with the rendered numpy dict (rgb [H, W, 3], depth [H, W], acc [H, W])
  and the true image float32 [H, W, 3] on the configured background (see
  `images_on_background`; the trainer sends the first one to TensorBoard).
  """
  make_draw = image_renderer.make_image_renderer(exp.renderer, exp.image)
  bg = background.parse(exp.config.data.background)
  test_ds = exp.test_ds
  camera = (test_ds.height, test_ds.width, test_ds.intrinsics)
  truths = images_on_background(test_ds, exp.config)[1]
  lpips_skipped = lpips.unavailable_reason(test_ds.height, test_ds.width)  # None: LPIPS runs

  def evaluate(variables, max_views=None, out_dir=None, on_view=None):
    count = len(test_ds) if max_views is None else min(max_views, len(test_ds))
    per_view = []
    draw = make_draw(variables)
    for i in range(count):
      out = draw(exp.rays(test_ds.poses[i], camera), bg)
      truth = truths[i]
      view = {"view": i, "psnr": float(metrics.psnr(out["rgb"], truth)),
              "ssim": float(metrics.ssim(out["rgb"], truth)),
              **geometry_errors(out, test_ds, i)}
      if lpips_skipped is None:
        view["lpips"] = float(lpips.lpips(out["rgb"], truth))
      per_view.append(view)
      if on_view is not None:
        on_view(i, out, truth)
      if out_dir:
        _write_eval_view(out_dir, i, out, truth, exp.near, exp.far)
    names = dict.fromkeys(name for v in per_view for name in v if name != "view")
    result = {name: float(np.mean([v[name] for v in per_view if name in v])) for name in names}
    if lpips_skipped is not None:
      result["lpips_skipped"] = lpips_skipped
    result["per_view"] = per_view
    if out_dir:
      with open(os.path.join(out_dir, "metrics.json"), "w") as f:
        json.dump(result, f, indent=2)
    return result

  return evaluate


OPAQUE, EMPTY = 0.99, 0.01  # true opacity of pixels scored for depth, and of empty pixels
FLOATER_ACC = 0.1  # rendered opacity from which an empty pixel counts as showing a floater
GEOMETRY_SCORES = ("depth_error", "empty_opacity", "floaters")  # what geometry_errors gives


def geometry_errors(out, dataset, index):
  """Geometry scores of one rendered view where the data has them, {} otherwise.

  depth_error: median |depth - true depth| over pixels the truth covers (opacity > OPAQUE), in
  scene units (needs `dataset.depths`). empty_opacity: the mean rendered opacity over pixels
  the truth leaves empty (opacity < EMPTY); floaters: the fraction of those that render with
  opacity > FLOATER_ACC (need `dataset.accs`). out: the render's numpy dict (depth, acc [H, W]).
  """
  scores = {}
  if dataset.accs is None:
    return scores
  true_acc = dataset.accs[index]
  empty = true_acc < EMPTY
  if np.any(empty):
    scores["empty_opacity"] = float(np.mean(out["acc"][empty]))
    scores["floaters"] = float(np.mean(out["acc"][empty] > FLOATER_ACC))
  opaque = true_acc > OPAQUE
  if dataset.depths is not None and np.any(opaque):
    scores["depth_error"] = float(np.median(np.abs(out["depth"] - dataset.depths[index])[opaque]))
  return scores


def _write_eval_view(out_dir, index, out, truth, near, far):
  os.makedirs(out_dir, exist_ok=True)
  panel = np.concatenate([to_uint8(out["rgb"]), colorize(out["depth"], near, far),
                          to_uint8(truth)], axis=1)
  imageio.imwrite(os.path.join(out_dir, f"view_{index:03d}.png"), panel)
  np.save(os.path.join(out_dir, f"depth_{index:03d}.npy"), out["depth"].astype(np.float32))


def render_frames(exp, variables, poses, scale=1.0):
  """Render `poses` (float32 [F, 4, 4]) through the training camera with `scale` times its pixels
  per side: yields numpy dicts rgb [H, W, 3], depth [H, W], acc [H, W]."""
  draw = image_renderer.make_image_renderer(exp.renderer, exp.image)(variables)
  bg = background.parse(exp.config.data.background)
  camera = exp.camera(scale)
  for pose in poses:
    yield draw(exp.rays(pose, camera), bg)


def video_poses(config, dataset):
  """The camera path of the video: float32 [F, 4, 4].

  Forward-facing data (NDC): a spiral around the mean camera, focused at a depth between the
  bounds (weighted towards near, in disparity, as LLFF does). Otherwise: a 360° orbit, the
  reference's pose_spherical path.
  """
  frames = config.render.video_frames
  if not config.data.ndc:
    return orbit_poses(frames, config.render.orbit_phi, config.render.orbit_radius)
  centre = np.eye(4, dtype=np.float32)
  centre[:3, :] = dataset.poses[:, :3, :].mean(axis=0)
  u, _, vt = np.linalg.svd(centre[:3, :3])
  centre[:3, :3] = u @ vt  # the nearest rotation to the mean rotation
  radii = np.percentile(np.abs(dataset.poses[:, :3, 3] - centre[:3, 3]), 90, axis=0)
  focus = 1.0 / (0.25 / dataset.near + 0.75 / dataset.far)
  return spiral_poses(centre, np.maximum(radii, 1e-3), focus, frames)


def render_video(exp, variables, out_dir, depth_npy=False, show_progress=True, scale=1.0,
                 poses=None):
  """A video as rgb.mp4 and depth.mp4 in `out_dir`: of `poses` (float32 [F, 4, 4]), or of the
  default path (see `video_poses`).

  depth_npy: also save the float depth of every frame as `depth_frames.npy`, float32 [F, H, W]
  (z-depth in scene units, see the module docstring). scale: frames have `scale` times the
  training images' pixels per side (see Experiment.camera). Returns the paths:
  {'rgb', 'depth'[, 'depth_npy']}.
  """
  os.makedirs(out_dir, exist_ok=True)
  poses = video_poses(exp.config, exp.train_ds) if poses is None else poses
  near, far = exp.near, exp.far
  rgb_frames, depth_frames, depths = [], [], []
  frames = render_frames(exp, variables, poses, scale)
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
      imageio.mimwrite(paths[name], frames, fps=exp.config.render.fps, macro_block_size=1)
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


def render_views(exp, variables, poses, out_dir, scale=1.0):
  """Render `poses` to `out_dir/view_XXX.png` (+ depth PNG and .npy). Returns the count.

  scale: images have `scale` times the training images' pixels per side.
  """
  os.makedirs(out_dir, exist_ok=True)
  near, far = exp.near, exp.far
  for i, out in enumerate(render_frames(exp, variables, poses, scale)):
    imageio.imwrite(os.path.join(out_dir, f"view_{i:03d}.png"), to_uint8(out["rgb"]))
    imageio.imwrite(os.path.join(out_dir, f"depth_{i:03d}.png"), colorize(out["depth"], near, far))
    np.save(os.path.join(out_dir, f"depth_{i:03d}.npy"), out["depth"].astype(np.float32))
  return len(poses)


MODES = ("eval", "video", "views", "path", "mesh")


def mesh_bound(config):
  """Half-size of the mesh export box: the scene box, else the grid's box, else 1.5 (the 360°
  built-in scenes fit in a ball of radius 1.2)."""
  if config.data.scene_bound > 0:
    return float(config.data.scene_bound)
  if config.model.encoding in ("grid", "hash"):
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


def path_poses(path, frames_per_segment, loop=False):
  """The poses float32 [F, 4, 4] of a camera path through the key cameras in `path`: a .json
  with 'keyframes' (what the viewer saves) or 'frames', or a .npy [K, 3|4, 4] (viewer.paths)."""
  from nerf_jax.viewer import paths  # pylint: disable=import-outside-toplevel  (pure numpy)
  keys = None
  if path.endswith(".json"):
    with open(path) as f:
      keys = json.load(f).get("keyframes")
  keys = load_poses(path) if not keys else np.asarray(keys, np.float32)
  return paths.interpolate(keys, frames_per_segment, loop)


def render(workdir, mode, poses_path="", out_dir="", depth_npy=False, resolution=128,
           threshold=50.0, bound=0.0, scale=1.0, path_frames=30):
  """Render `mode` (one of MODES) from the newest checkpoint of `workdir`; returns what it wrote.

  depth_npy: video mode also writes float depth_frames.npy. resolution, threshold, bound: mesh
  mode (see surface.extract). scale: video and views modes render `scale` times the training
  images' pixels per side. path_frames: path mode, frames from one key camera to the next.
  """
  if not os.path.isdir(workdir):
    raise FileNotFoundError(f"--workdir={workdir}: no such directory")
  if scale <= 0:
    raise ValueError(f"--scale={scale}: must be positive")
  if mode in ("views", "path") and not poses_path:
    raise ValueError(f"--mode={mode} needs --poses=FILE (.npy [N,4,4] or .json with frames)")
  if mode in ("views", "path") and not os.path.exists(poses_path):
    raise FileNotFoundError(f"{poses_path}: no such poses file")
  exp, state = experiment.restore(workdir)
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
    result = make_evaluator(exp)(variables, out_dir=out_dir)
    print(f"test PSNR {result['psnr']:.2f} dB, SSIM {result['ssim']:.4f}, "
          f"{lpips.describe(result)} over {len(result['per_view'])} views -> {out_dir}")
    return result
  if mode in ("video", "path"):
    poses = path_poses(poses_path, path_frames) if mode == "path" else None
    paths = render_video(exp, variables, out_dir, depth_npy=depth_npy, scale=scale, poses=poses)
    print(f"wrote {', '.join(paths.values())}")
    return paths
  count = render_views(exp, variables, load_poses(poses_path), out_dir, scale)
  print(f"wrote {count} views to {out_dir}")
  return out_dir
