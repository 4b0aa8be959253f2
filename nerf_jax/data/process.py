"""Photos or a video in, a posed dataset out: `python -m nerf_jax.data.process`, `nerf-process`.

  nerf-process --images=photos/ --out=data/mine          # a folder of JPEG/PNG photos
  nerf-process --video=walk.mp4 --num_frames=80 --out=data/mine

Writes OUT/images/ (the photos, or the sampled video frames), OUT/transforms.json (nerfstudio
format, `nerf_jax.data.nerfstudio`), OUT/sparse_pc.ply (the sparse points) and OUT/colmap/
(COLMAP's database, every model in models/, the one used in sparse/0). Masks: a masks/ folder
beside the photos' folder (`nerf_jax.data.masks`: same names, white = keep) is passed through as
OUT/masks/<image stem>.png (255 keep, 0 ignore) and each frame's mask_path. The scene is re-oriented
(z up) and scaled into the box [-1, 1]^3 (`nerf_jax.data.orient`); near and far are stored in
the file. Needs the `capture` extra (pycolmap): pip install -e ".[capture]".
"""

import os
import shutil
import time

import numpy as np

from nerf_jax.data import masks as masks_lib, nerfstudio, orient, pointcloud, sfm, validate
from nerf_jax.data.dataset import DataError

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png")


def list_images(image_dir, single_camera=True):
  """Sorted image file names in `image_dir`; DataError if there is none or one is unreadable,
  or (single_camera: the photos share one camera) the sizes differ."""
  if not os.path.isdir(image_dir):
    raise DataError(f"--images={image_dir}: no such directory")
  names = sorted(n for n in os.listdir(image_dir) if n.lower().endswith(IMAGE_EXTENSIONS))
  if not names:
    raise DataError(f"--images={image_dir}: no images ({', '.join(IMAGE_EXTENSIONS)}) found")
  sizes = {}
  for name in names:
    shape = validate.read_image(os.path.join(image_dir, name)).shape
    sizes.setdefault(shape[:2], name)
  if single_camera and len(sizes) > 1:
    (s1, n1), (s2, n2) = list(sizes.items())[:2]
    raise DataError(f"--images={image_dir}: images have different sizes ({n1} is "
                    f"{s1[1]}x{s1[0]}, {n2} is {s2[1]}x{s2[0]}); use photos from one camera "
                    "at one resolution, or pass --nosingle_camera for photos from many cameras")
  return names


def sample_video(video, num_frames, image_dir):
  """Write `num_frames` evenly spaced frames of `video` as image_dir/frame_XXXXX.jpg."""
  import imageio.v2 as imageio  # pylint: disable=import-outside-toplevel
  if not os.path.isfile(video):
    raise DataError(f"--video={video}: no such file")
  if num_frames < 2:
    raise DataError(f"--num_frames={num_frames}: need at least 2 frames")
  try:
    reader = imageio.get_reader(video, "ffmpeg")
    count = reader.count_frames()
    wanted = set(np.linspace(0, count - 1, min(num_frames, count)).round().astype(int).tolist())
    written = 0
    for k, frame in enumerate(reader):
      if k in wanted:
        imageio.imwrite(os.path.join(image_dir, f"frame_{k:05d}.jpg"), frame[..., :3],
                        quality=95)
        written += 1
    reader.close()
  except (OSError, RuntimeError, ValueError, IndexError) as e:
    raise DataError(f"--video={video}: cannot read the video ({type(e).__name__}: "
                    f"{str(e).splitlines()[0] if str(e) else ''})") from None
  if written < 2:
    raise DataError(f"--video={video}: only {written} frame(s) could be read")


def _camera_fields(intrinsics, dist, size):
  """transforms.json's camera fields of intrinsics float [4] (fx, fy, cx, cy), dist float [4]
  (k1, k2, p1, p2) and size (height, width)."""
  fx, fy, cx, cy = (float(v) for v in intrinsics)
  k1, k2, p1, p2 = (float(v) for v in dist)
  return {"fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": int(size[1]), "h": int(size[0]),
          "k1": k1, "k2": k2, "p1": p1, "p2": p2}


def write_dataset(out_dir, rec, image_subdir="images", mask_paths=None):
  """Normalise `rec` (sfm.Reconstruction) and write transforms.json and sparse_pc.ply.
  mask_paths: None, or {image name: mask_path relative to out_dir} (`pass_masks`).

  Returns {'transform': float64 [4, 4] (COLMAP world -> ours), 'near', 'far', 'orbit_radius',
  'orbit_phi'}.
  """
  transform = orient.normalize(rec.poses, rec.points)
  poses, points = orient.apply(transform, rec.poses, rec.points)
  near, far = orient.depth_bounds(poses, points)
  radius, phi = orient.orbit(poses)
  shared = len(set(rec.camera_ids.tolist())) == 1
  cameras = [_camera_fields(k, d, size)
             for k, d, size in zip(rec.intrinsics, rec.dist, rec.image_sizes())]
  pointcloud.write_ply(os.path.join(out_dir, "sparse_pc.ply"), points, rec.colors)
  frames = [(f"{image_subdir}/{name}", pose) for name, pose in zip(rec.names, poses)]
  extra = {"applied_transform": transform[:3].tolist(), "ply_file_path": "sparse_pc.ply",
           "near": near, "far": far, "nerf_jax_normalized": True,
           "orbit_radius": radius, "orbit_phi": phi}
  nerfstudio.write(out_dir, frames, cameras[0] if shared else cameras, extra,
                   None if mask_paths is None else [mask_paths.get(n) for n in rec.names])
  return {"transform": transform, "near": near, "far": far, "orbit_radius": radius,
          "orbit_phi": phi}


def _fresh(folder):
  """Make `folder` empty: what an earlier run left there would mix in."""
  shutil.rmtree(folder, ignore_errors=True)
  os.makedirs(folder)


def _gather(image_dir, images, video, num_frames, log, single_camera=True):
  """Fill `image_dir` with the photos or the video's frames; returns their sorted names.
  single_camera: the photos must share one size (`list_images`)."""
  if video:
    log(f"[1/4] sampling {num_frames} frames of {video}")
    _fresh(image_dir)
    sample_video(video, num_frames, image_dir)
    return list_images(image_dir)
  names = list_images(images, single_camera)
  log(f"[1/4] {len(names)} images in {images}")
  if os.path.realpath(images) != os.path.realpath(image_dir):
    _fresh(image_dir)
    for name in names:
      shutil.copy2(os.path.join(images, name), os.path.join(image_dir, name))
  return names


def pass_masks(images, names, out_dir):
  """The masks/ folder beside the photos' folder `images` (for the photos `names`) written as
  OUT/masks/<stem>.png; returns {name: mask_path relative to out_dir}, or None without masks/.
  DataError naming the photo whose mask is missing, of the wrong size or ignores every pixel."""
  source = os.path.dirname(os.path.normpath(images))
  found = masks_lib.folder_masks(source, names)
  if found is None:
    return None
  for name, mask in zip(names, found):
    size = validate.read_image(os.path.join(images, name)).shape
    masks_lib.check(mask, size, os.path.join(source, masks_lib.MASKS_DIR, name))
  _fresh(os.path.join(out_dir, masks_lib.MASKS_DIR))  # after reading: it may be the source
  paths = {}
  for name, mask in zip(names, found):
    paths[name] = f"{masks_lib.MASKS_DIR}/{os.path.splitext(name)[0]}.png"
    masks_lib.write(os.path.join(out_dir, paths[name]), mask)
  return paths


def process(out_dir, images="", video="", num_frames=100, matcher="auto",
            camera_model="SIMPLE_RADIAL", single_camera=True, min_registered=0.5, log=print,
            num_threads=-1, ordered=False):
  """Photos (`images`, a directory) or a `video` -> a posed dataset in `out_dir`.

  matcher: 'auto' (`sfm.choose_matcher`: every pair of unordered photos, neighbours only for
  video frames or, with `ordered`, photos taken in file-name order), 'exhaustive' or
  'sequential'; the choice and why are logged on one line.

  single_camera: bool, all photos share one camera (and size); False: one camera per photo,
  photos of different sizes accepted, each frame of transforms.json with its own camera.
  min_registered: float, the fraction of images that must be registered (else SfmError).
  num_threads: COLMAP's threads (-1 = all cores; 1 = the same result on every run: with
  several threads the order of matches and registrations varies, and so can the outcome).
  Returns a summary dict: num_images, num_registered, mean_error (px), num_points, seconds
  {stage: s}, and `write_dataset`'s fields.
  """
  if bool(images) == bool(video):
    raise DataError("give exactly one of --images=DIR or --video=FILE")
  if not out_dir:
    raise DataError("--out: an output directory is required")
  sfm.require_pycolmap()  # before any work: a missing extra is the first thing to say
  start = time.perf_counter()
  for stale in (nerfstudio.FILENAME, "sparse_pc.ply"):  # a failed run must not leave old ones
    if os.path.isfile(os.path.join(out_dir, stale)):
      os.remove(os.path.join(out_dir, stale))
  image_dir = os.path.join(out_dir, "images")
  names = _gather(image_dir, images, video, num_frames, log, single_camera)
  mask_paths = None if video else pass_masks(images, names, out_dir)
  if mask_paths is not None:
    log(f"      {len(mask_paths)} masks passed through to "
        f"{os.path.join(out_dir, masks_lib.MASKS_DIR)}")
  work_dir = os.path.join(out_dir, "colmap")
  _fresh(work_dir)  # a stale database would mix in old images
  os.makedirs(os.path.join(work_dir, "models"))
  matcher, why = sfm.choose_matcher(matcher, len(names), ordered=ordered, video=bool(video))
  log(f"[2/4] structure from motion ({matcher} matching, {camera_model} camera)")
  log(f"      {matcher} matching: {why}")
  rec, seconds = sfm.reconstruct(image_dir, work_dir, matcher, camera_model, single_camera,
                                 num_threads=num_threads, log=log)
  registered = 0 if rec is None else len(rec.names)
  if registered < max(3, min_registered * len(names)):
    raise sfm.SfmError(
        f"only {registered} of {len(names)} images registered (need {min_registered:.0%}): take "
        "photos with more overlap (each area in 3+ photos), avoid blur and blank walls" +
        (", or try --matcher=exhaustive" if matcher == "sequential" else ""))
  log("[3/4] re-orienting and scaling into the scene box")
  written = write_dataset(out_dir, rec, mask_paths=mask_paths)
  seconds["total"] = time.perf_counter() - start
  summary = {"num_images": len(names), "num_registered": registered,
             "mean_error": rec.mean_error, "num_points": len(rec.points), "seconds": seconds,
             "camera": rec.intrinsics[0].tolist() + rec.dist[0].tolist(), **written}
  log(f"[4/4] wrote {os.path.join(out_dir, nerfstudio.FILENAME)}: {registered}/{len(names)} "
      f"images registered, mean reprojection error {rec.mean_error:.2f} px, "
      f"{len(rec.points)} points, {seconds['total']:.1f} s")
  name = os.path.basename(os.path.normpath(out_dir))
  log("train and render it with (the config and the photos' size decided from the data, "
      "docs/auto.md):\n"
      f"  python train.py --config=auto --config.data.path={out_dir} --workdir=runs/{name}\n"
      "or choose the config yourself: --config=capture for a room or a garden (the whole "
      "scene); for an object alone on an empty background, with an orbit video:\n"
      f"  python train.py --config=fast --config.data.path={out_dir} "
      f"--config.render.orbit_radius={written['orbit_radius']:.2f} "
      f"--config.render.orbit_phi={written['orbit_phi']:.0f} --workdir=runs/{name}")
  return summary


# Exceptions whose message is the whole story for the user of nerf-process (as for nerf-train).
USER_ERRORS = (DataError, FileNotFoundError, ValueError)


def main():
  """Define the flags, parse them (one-line errors: backend/errors.py) and process."""
  from absl import app, flags  # pylint: disable=import-outside-toplevel
  from nerf_jax.backend import errors  # pylint: disable=import-outside-toplevel
  images = flags.DEFINE_string("images", "", "Directory of photos (.jpg, .jpeg, .png).")
  video = flags.DEFINE_string("video", "", "A video file to sample frames from.")
  num_frames = flags.DEFINE_integer("num_frames", 100, "--video: frames sampled evenly.")
  out = flags.DEFINE_string("out", "", "Output directory (the dataset).")
  matcher = flags.DEFINE_enum("matcher", "auto", ["auto", "exhaustive", "sequential"],
                              "Feature matching; auto = every pair of unordered photos, "
                              "sequential for a video or --ordered photos.")
  ordered = flags.DEFINE_bool("ordered", False, "The photos are an ordered capture (taken in "
                              "file-name order): auto matches each with its neighbours.")
  camera_model = flags.DEFINE_enum("camera_model", "SIMPLE_RADIAL",
                                   list(nerfstudio.lens.COLMAP_PARAMS), "COLMAP camera model.")
  single_camera = flags.DEFINE_bool("single_camera", True, "All photos share one camera; "
                                    "--nosingle_camera: one per photo (sizes may differ).")
  min_registered = flags.DEFINE_float("min_registered", 0.5, "Fail unless this fraction of "
                                      "the images is registered.")

  def run(argv):
    del argv
    errors.run_main(lambda: process(out.value, images.value, video.value, num_frames.value,
                                    matcher.value, camera_model.value, single_camera.value,
                                    min_registered.value, ordered=ordered.value),
                   USER_ERRORS)

  app.run(run, flags_parser=errors.parse_flags)


if __name__ == "__main__":
  main()
