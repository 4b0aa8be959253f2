"""The capture benchmark (issue 14): photos without poses -> nerf-process -> train -> video.

  python -m nerf_jax.bench.capture --out=runs/capture_bench --train_seconds=300

1. photographs `--views` JPEG views (`--size` pixels, quality 95) of the noise-textured scene
   `nerf_jax.data.scenes.capture` (or a built-in scene, `--scene=detail`) on a ring;
2. runs the first command, `python -m nerf_jax.data.process --images=... --out=...`, and scores
   the recovered cameras against the true ones after one similarity alignment (median rotation
   error, camera-centre error relative to the camera distance, focal error);
3. trains configs/fast.py for `--train_seconds` on three folders that share the processed
   folder's images, world frame (its up axis, centre and scale), near/far and held-out views
   (every 8th registered photo), so that only the cameras differ:
     sfm          the processed folder itself: SfM poses, SfM intrinsics and lens;
     true_poses   the true poses mapped into the processed frame (`true_in_frame`), SfM
                  intrinsics and lens: the photos are resampled exactly as in `sfm`, so this
                  run differs from it in the poses alone (the issue's comparison);
     true_cameras the true poses and the true pinhole intrinsics: the original photos, not
                  resampled (the held-out images differ from the other two by that resampling);
   each model is scored at the held-out poses of its own folder (a user's SfM run can only
   render held-out photos at the poses SfM found for them), and the `sfm` model again at the
   true held-out poses of `true_poses` (same images), which charges it with the pose errors of
   the held-out views too. Then `render.py --mode=video` on the `sfm` run; writes everything to
   `--out`, a JSON record (record.json, stamped as every benchmark record: records.py) and
   summary.txt.
"""

import dataclasses
import json
import os
import sys

import imageio.v3 as iio
import numpy as np

from nerf_jax.bench import child, records
from nerf_jax.data import nerfstudio, orient, pointcloud
from nerf_jax.data.scenes import capture

RUNS = ("sfm", "true_poses", "true_cameras")


def photograph(folder, num_views, size, scene="capture"):
  """Write the views as JPEGs; returns (true poses float32 [N, 4, 4], focal float)."""
  os.makedirs(folder, exist_ok=True)
  if scene == "capture":
    focal = 500.0 * size / 400.0  # the field of view of the 128-pixel test capture
    poses = capture.ring_poses(num_views)
    images = [capture.render(p, size, size, (focal, focal, size / 2, size / 2)) for p in poses]
  else:
    from nerf_jax.data import scenes  # pylint: disable=import-outside-toplevel
    focal = scenes.TINY_NERF_FOCAL * size / 100
    dataset = scenes.make_dataset(scene, num_views, size, size, focal, pixel_center=0.5)
    poses, images = dataset.poses, dataset.images
  for k, image in enumerate(images):
    iio.imwrite(os.path.join(folder, f"view_{k:03d}.jpg"),
                (np.clip(image, 0, 1) * 255).round().astype(np.uint8), quality=95)
  return np.asarray(poses), focal


def similarity(src, dst):
  """Umeyama: (s, R, t) minimising |s R src + t - dst|^2 over float [N, 3] point sets."""
  mu_s, mu_d = src.mean(0), dst.mean(0)
  u, sing, vt = np.linalg.svd((dst - mu_d).T @ (src - mu_s) / len(src))
  sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
  rot = u @ sign @ vt
  scale = np.trace(np.diag(sing) @ sign) / ((src - mu_s) ** 2).sum(-1).mean()
  return scale, rot, mu_d - scale * rot @ mu_s


def alignment(poses, true):
  """The one similarity alignment: float64 [4, 4] taking the frame of `poses` onto that of
  `true` (both float [N, 4, 4] camera-to-world, the same cameras in the same order), fitted to
  the camera centres by least squares (`similarity`)."""
  scale, rot, trans = similarity(np.asarray(poses, np.float64)[:, :3, 3],
                                 np.asarray(true, np.float64)[:, :3, 3])
  transform = np.eye(4)
  transform[:3, :3], transform[:3, 3] = scale * rot, trans
  return transform


def pose_errors(poses, true):
  """(rotation errors in degrees, centre errors / distance of the true camera to the origin),
  each float64 [N], after aligning `poses` to `true` (float [N, 4, 4]) by `alignment`."""
  poses, true = np.asarray(poses, np.float64), np.asarray(true, np.float64)
  transform = alignment(poses, true)
  rot = transform[:3, :3] / np.cbrt(np.linalg.det(transform[:3, :3]))
  centres = poses[:, :3, 3] @ transform[:3, :3].T + transform[:3, 3]
  centre = (np.linalg.norm(centres - true[:, :3, 3], axis=-1)
            / np.linalg.norm(true[:, :3, 3], axis=-1))
  rel = np.einsum("ij,njk,nlk->nil", rot, poses[:, :3, :3], true[:, :3, :3])
  cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)  # float64: 0.01° resolves
  return np.degrees(np.arccos(cos)), centre


def true_in_frame(poses, true):
  """The true cameras in the frame of `poses`: float32 [N, 4, 4], `true` mapped by the inverse
  of `alignment(poses, true)` (the similarity `pose_errors` measures with). poses, true: float
  [N, 4, 4] camera-to-world, the same cameras in the same order."""
  return orient.apply(np.linalg.inv(alignment(poses, true)), true)[0]  # a similarity's inverse


def write_true_folder(folder, processed, true, camera=None):
  """A copy of the processed folder's transforms.json in `folder` with only the cameras changed.

  processed: a folder nerf-process wrote (one shared camera). true: float [N, 4, 4], the true
  camera-to-world of its frames, in their order, in the truth's own frame: they are written
  mapped into the processed frame (`true_in_frame`). camera: None keeps the processed camera
  (intrinsics and lens), else a dict of fl_x, fl_y, cx, cy (and k1, k2, p1, p2, default 0)
  replaces it. The photos are the processed folder's (images/ is a symbolic link); near, far,
  the frames' order and so the held-out views stay as they are. Returns the poses written,
  float32 [N, 4, 4].
  """
  with open(os.path.join(processed, nerfstudio.FILENAME)) as f:
    meta = json.load(f)
  frames = meta["frames"]
  if len(true) != len(frames) or any("fl_x" in frame for frame in frames):
    raise ValueError(f"{processed}: expected {len(true)} frames sharing one camera")
  poses = true_in_frame([frame["transform_matrix"] for frame in frames], true)
  for frame, pose in zip(frames, poses):
    frame["transform_matrix"] = pose.tolist()
  if camera is not None:
    meta.update({"k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0, **camera})
  for key in ("applied_transform", "ply_file_path"):  # about COLMAP's model, not these poses
    meta.pop(key, None)
  os.makedirs(folder, exist_ok=True)
  link = os.path.join(folder, "images")
  if not os.path.exists(link):
    os.symlink(os.path.abspath(os.path.join(processed, "images")), link)
  with open(os.path.join(folder, nerfstudio.FILENAME), "w") as f:
    json.dump(meta, f, indent=2)
  return poses


def held_out(workdir, folder):
  """The held-out views of the transforms.json `folder`, loaded as the run in `workdir` loads
  its data (its factor, background, split; moved as its world was, data.focus or data.subject):
  a Dataset."""
  # pylint: disable-next=import-outside-toplevel
  from nerf_jax.run import builders, config_lib, from_data, subject
  from nerf_jax.data import loaders  # pylint: disable=import-outside-toplevel
  config = config_lib.load_saved(workdir)
  data = config.data.to_dict()
  data["path"] = folder
  test_ds = loaders.load_dataset(builders.data_settings(data))[1]
  if config.data.focus or config.data.subject:  # the run's world was moved: move these too
    train_ds = loaders.load_dataset(builders.data_settings(config.data))[0]
    test_ds = subject.with_subject(config, train_ds, test_ds)[2]
    test_ds = from_data.with_focus(config, train_ds, test_ds)[1]
  return test_ds


def evaluate_at(workdir, test_ds):
  """The newest checkpoint of `workdir` scored on the views of `test_ds` (a Dataset in the run's
  world frame, at its image size): builders.make_evaluator's {'psnr', 'ssim', ...}."""
  # pylint: disable-next=import-outside-toplevel
  from nerf_jax.run import builders, experiment
  exp, state = experiment.restore(workdir)
  return builders.make_evaluator(dataclasses.replace(exp, test_ds=test_ds))(state.variables)


def _scores(metrics):
  keep = ("psnr", "ssim", "lpips", "steps", "train_seconds")
  return {k: metrics[k] for k in keep if k in metrics}


def summary(record):
  """The comparison as lines of text (record: what `main` writes to record.json)."""
  runs = record["runs"]
  lines = [f"held-out views: {record['held_out']} of {record['registered']} registered "
           "(every 8th); one world frame (the processed folder's), near/far and scene box",
           f"{'run':<14} {'poses':<32} {'intrinsics':<26} {'PSNR':>8} {'SSIM':>6} {'LPIPS':>6} "
           f"{'steps':>6}"]
  what = {"sfm": ("SfM", "SfM (resampled photos)"),
          "true_poses": ("true, mapped into the SfM frame", "SfM (resampled photos)"),
          "true_cameras": ("true, mapped into the SfM frame", "true (original photos)"),
          "sfm@true": ("true (held-out views only)", "SfM (resampled photos)")}
  for name in (*RUNS, "sfm@true"):
    run = runs.get(name)
    if run:
      lpips = f"{run['lpips']:.3f}" if "lpips" in run else "-"
      lines.append(f"{name:<14} {what[name][0]:<32} {what[name][1]:<26} {run['psnr']:>5.2f} dB "
                   f"{run['ssim']:>6.3f} {lpips:>6} {run.get('steps', '(sfm)'):>6}")
  lines.append(f"sfm - true_poses: {record['psnr_sfm_minus_true_poses']:+.2f} dB (goal: within "
               "1.5 dB); each model scored at its own folder's held-out poses; sfm@true is the "
               "sfm model at the true held-out poses")
  return lines


def _run(cmd, log_path):
  """Run a command (from the repository root: train.py, render.py), its output into log_path
  after the command line; returns (seconds, output). RuntimeError with its last line if it
  fails."""
  code, seconds = child.run_logged(cmd, log_path, environment={**os.environ, "PYTHONPATH": "."},
                                   command_line=True)
  with open(log_path) as f:
    output = f.read().split("\n", 1)[1]
  if code:
    raise RuntimeError(f"{' '.join(cmd)} failed: {output.strip().splitlines()[-1:]}")
  return seconds, output


def _train(root, folders, seconds, extra):
  """Train configs/fast.py for `seconds` on each of `folders` ({name: folder}), with the flags
  `extra` (list of str) added; returns {name: scores at the folder's own held-out poses}."""
  scores = {}
  for name, folder in folders.items():
    workdir = os.path.join(root, f"train_{name}")
    _run([sys.executable, "train.py", "--config=configs/fast.py",
          f"--config.data.path={folder}", f"--config.train.max_seconds={seconds}",
          "--config.render.after_training=False", f"--workdir={workdir}", *extra],
         os.path.join(root, f"train_{name}.log"))
    with open(os.path.join(workdir, "metrics.json")) as f:
      scores[name] = _scores(json.load(f))
  return scores


def compare(root, processed, true, focal, size, seconds, extra=()):
  """Train and score the three runs of the module docstring (processed: the nerf-process
  folder; true: float [N, 4, 4], the true poses of its frames, in order; focal, size: the true
  camera; seconds, extra: each run's budget and further train.py flags); returns the record's
  fields."""
  folders = {"sfm": processed, "true_poses": os.path.join(root, "true_poses"),
             "true_cameras": os.path.join(root, "true_cameras")}
  write_true_folder(folders["true_poses"], processed, true)
  write_true_folder(folders["true_cameras"], processed, true,
                    {"fl_x": focal, "fl_y": focal, "cx": size / 2, "cy": size / 2})
  runs = _train(root, folders, seconds, list(extra))
  sfm_workdir = os.path.join(root, "train_sfm")
  test_sfm, test_true = (held_out(sfm_workdir, folders[n]) for n in ("sfm", "true_poses"))
  if not np.array_equal(test_sfm.images, test_true.images):
    raise RuntimeError("the sfm and true_poses folders give different held-out images")
  runs["sfm@true"] = _scores(evaluate_at(sfm_workdir, test_true))
  return {"runs": runs, "held_out": len(test_sfm),
          "psnr_sfm_minus_true_poses": runs["sfm"]["psnr"] - runs["true_poses"]["psnr"]}


def _run_machine(root):
  """The machine record the sfm run measured while it trained (its metrics.json's), or None
  where nothing trained (records.stamp then describes the machine: no child follows)."""
  path = os.path.join(root, "train_sfm", "metrics.json")
  if not os.path.isfile(path):
    return None
  with open(path) as f:
    return json.load(f).get("machine")


def _write_record(root, record):
  """record.json, and summary.txt with the comparison when there is one; prints both."""
  with open(os.path.join(root, "record.json"), "w") as f:
    json.dump(record, f, indent=2)
  print(json.dumps(record, indent=2))
  if "runs" in record:
    text = "\n".join(summary(record))
    with open(os.path.join(root, "summary.txt"), "w") as f:
      f.write(text + "\n")
    print(text)


def main():
  from absl import app, flags  # pylint: disable=import-outside-toplevel
  out = flags.DEFINE_string("out", "runs/capture_bench", "Output directory.")
  views = flags.DEFINE_integer("views", 40, "Photographs.")
  size = flags.DEFINE_integer("size", 400, "Pixels per side.")
  scene = flags.DEFINE_string("scene", "capture", "'capture' or a built-in scene (detail).")
  camera_model = flags.DEFINE_string("camera_model", "SIMPLE_RADIAL", "nerf-process's "
                                     "--camera_model.")
  train_seconds = flags.DEFINE_float("train_seconds", 300.0, "Training budget per model "
                                     "(0 = skip training).")
  video = flags.DEFINE_bool("video", True, "Render the sfm run's video after training.")

  def run(argv):
    del argv
    root = out.value
    photos, processed = os.path.join(root, "photos"), os.path.join(root, "processed")
    true_poses, focal = photograph(photos, views.value, size.value, scene.value)
    record = {"views": views.value, "size": size.value, "scene": scene.value,
              "camera_model": camera_model.value}
    seconds, log = _run([sys.executable, "-m", "nerf_jax.data.process", f"--images={photos}",
                         f"--out={processed}", f"--camera_model={camera_model.value}"],
                        os.path.join(root, "process.log"))
    print(log)
    with open(os.path.join(processed, nerfstudio.FILENAME)) as f:
      meta = json.load(f)
    index = [int(f["file_path"][-7:-4]) for f in meta["frames"]]
    true = true_poses[index].astype(np.float64)
    poses = np.array([f["transform_matrix"] for f in meta["frames"]])
    rot_err, centre_err = pose_errors(poses, true)
    record.update(
        process_seconds=seconds, registered=len(index),
        median_rotation_deg=float(np.median(rot_err)), max_rotation_deg=float(rot_err.max()),
        median_centre_error=float(np.median(centre_err)), max_centre_error=float(centre_err.max()),
        focal_error=float(meta["fl_x"] / focal - 1), k1=meta["k1"],
        points=len(pointcloud.read_ply(os.path.join(processed, "sparse_pc.ply"))[0]))
    if train_seconds.value > 0:
      orbit = [f"--config.render.orbit_radius={meta['orbit_radius']:.2f}",  # for the video
               f"--config.render.orbit_phi={meta['orbit_phi']:.0f}"]
      record.update(compare(root, processed, true, focal, size.value, train_seconds.value,
                            orbit))
    record = records.stamp(record, _run_machine(root))
    _write_record(root, record)
    if train_seconds.value > 0 and video.value:
      record["video_seconds"], _ = _run(
          [sys.executable, "render.py", f"--workdir={root}/train_sfm", "--mode=video"],
          os.path.join(root, "render.log"))
      _write_record(root, record)

  app.run(run)


if __name__ == "__main__":
  main()
