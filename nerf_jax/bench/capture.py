"""The capture benchmark (issue 14): photos without poses -> nerf-process -> train -> video.

  python -m nerf_jax.bench.capture --out=runs/capture_bench --train_seconds=300

1. photographs `--views` JPEG views (`--size` pixels, quality 95) of the noise-textured scene
   `nerf_jax.scenes.capture` (or the built-in `--scene=detail` when it exists) on a ring;
2. runs the first command, `python -m nerf_jax.data.process --images=... --out=...`, and scores
   the recovered cameras against the true ones after one similarity alignment (median rotation
   error, camera-centre error relative to the camera distance, focal error);
3. runs `train.py` with configs/fast.py for `--train_seconds` on the processed folder and on a
   folder with the true poses and focal (same images, same held-out views: every 8th), then
   `render.py --mode=video` on the first; writes everything to `--out` and a JSON record.
"""

import json
import os
import subprocess
import sys
import time

import imageio.v3 as iio
import numpy as np

from nerf_jax.data import nerfstudio, pointcloud
from nerf_jax.scenes import capture


def photograph(folder, num_views, size, scene="capture"):
  """Write the views as JPEGs; returns (true poses float32 [N, 4, 4], focal float)."""
  os.makedirs(folder, exist_ok=True)
  if scene == "capture":
    focal = 500.0 * size / 400.0  # the field of view of the 128-pixel test capture
    poses = capture.ring_poses(num_views)
    images = [capture.render(p, size, size, (focal, focal, size / 2, size / 2)) for p in poses]
  else:
    from nerf_jax import scenes  # pylint: disable=import-outside-toplevel
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


def pose_errors(poses, true):
  """(rotation errors in degrees, centre errors / distance of the true camera to the origin),
  each float64 [N], after aligning `poses` to `true` (float [N, 4, 4]) by one similarity."""
  scale, rot, trans = similarity(poses[:, :3, 3], true[:, :3, 3])
  centres = scale * poses[:, :3, 3] @ rot.T + trans
  centre = (np.linalg.norm(centres - true[:, :3, 3], axis=-1)
            / np.linalg.norm(true[:, :3, 3], axis=-1))
  rel = np.einsum("ij,njk,nlk->nil", rot, poses[:, :3, :3], true[:, :3, :3])
  cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)
  return np.degrees(np.arccos(cos)), centre


def write_true_folder(folder, photos, poses, focal, size):
  """A transforms.json folder with the true cameras and the same photos (symlinked)."""
  os.makedirs(folder, exist_ok=True)
  link = os.path.join(folder, "images")
  if not os.path.exists(link):
    os.symlink(os.path.abspath(photos), link)
  names = sorted(os.listdir(photos))
  centres = poses[:, :3, 3]
  distance = np.linalg.norm(centres, axis=-1)
  camera = {"fl_x": focal, "fl_y": focal, "cx": size / 2, "cy": size / 2, "w": size, "h": size,
            "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}
  nerfstudio.write(folder, [(f"images/{n}", p) for n, p in zip(names, poses)], camera,
                   {"near": float(distance.min() - 1.7), "far": float(distance.max() + 1.7),
                    "nerf_jax_normalized": True})


def _run(cmd, log_path):
  """Run a command, tee its output into log_path; returns (seconds, output)."""
  start = time.perf_counter()
  result = subprocess.run(cmd, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": "."})
  seconds = time.perf_counter() - start
  with open(log_path, "w") as f:
    f.write("$ " + " ".join(cmd) + "\n" + result.stdout + result.stderr)
  if result.returncode:
    raise RuntimeError(f"{' '.join(cmd)} failed: {result.stderr.strip().splitlines()[-1:]}")
  return seconds, result.stdout + result.stderr


def main():
  from absl import app, flags  # pylint: disable=import-outside-toplevel
  out = flags.DEFINE_string("out", "runs/capture_bench", "Output directory.")
  views = flags.DEFINE_integer("views", 40, "Photographs.")
  size = flags.DEFINE_integer("size", 400, "Pixels per side.")
  scene = flags.DEFINE_string("scene", "capture", "'capture' or a built-in scene (detail).")
  train_seconds = flags.DEFINE_float("train_seconds", 300.0, "Training budget per model "
                                     "(0 = skip training).")

  def run(argv):
    del argv
    root = out.value
    photos, processed, truth = (os.path.join(root, n) for n in ("photos", "processed", "true"))
    true_poses, focal = photograph(photos, views.value, size.value, scene.value)
    record = {"views": views.value, "size": size.value, "scene": scene.value}
    seconds, log = _run([sys.executable, "-m", "nerf_jax.data.process", f"--images={photos}",
                         f"--out={processed}"], os.path.join(root, "process.log"))
    print(log)
    meta = json.load(open(os.path.join(processed, nerfstudio.FILENAME)))
    index = [int(f["file_path"][-7:-4]) for f in meta["frames"]]
    poses = np.array([f["transform_matrix"] for f in meta["frames"]])
    rot_err, centre_err = pose_errors(poses, true_poses[index].astype(np.float64))
    record.update(
        process_seconds=seconds, registered=len(index),
        median_rotation_deg=float(np.median(rot_err)), max_rotation_deg=float(rot_err.max()),
        median_centre_error=float(np.median(centre_err)), max_centre_error=float(centre_err.max()),
        focal_error=float(meta["fl_x"] / focal - 1), k1=meta["k1"],
        points=len(pointcloud.read_ply(os.path.join(processed, "sparse_pc.ply"))[0]))
    if train_seconds.value > 0:
      write_true_folder(truth, photos, true_poses, focal, size.value)
      for name, folder in (("processed", processed), ("true", truth)):
        workdir = os.path.join(root, f"train_{name}")
        cmd = [sys.executable, "train.py", "--config=configs/fast.py",
               f"--config.data.path={folder}", f"--config.train.max_seconds={train_seconds.value}",
               "--config.render.after_training=False", f"--workdir={workdir}"]
        if name == "processed":
          cmd += [f"--config.render.orbit_radius={meta['orbit_radius']:.2f}",
                  f"--config.render.orbit_phi={meta['orbit_phi']:.0f}"]
        _run(cmd, os.path.join(root, f"train_{name}.log"))
        metrics = json.load(open(os.path.join(workdir, "metrics.json")))
        record[f"psnr_{name}"] = metrics["psnr"]
        record[f"ssim_{name}"] = metrics["ssim"]
      video_s, _ = _run([sys.executable, "render.py", f"--workdir={root}/train_processed",
                         "--mode=video"], os.path.join(root, "render.log"))
      record["video_seconds"] = video_s
    with open(os.path.join(root, "record.json"), "w") as f:
      json.dump(record, f, indent=2)
    print(json.dumps(record, indent=2))

  app.run(run)


if __name__ == "__main__":
  main()
