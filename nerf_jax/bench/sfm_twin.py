"""Does the SfM twin (`landmark_sfm`, nerf_jax/data/scenes/landmark_sfm.py) fail the way a real
collection posed with one shared focal does? For `landmark` (true poses) and `landmark_sfm` (the
poses a one-focal reconstruction gives), on the same training photos, this prints:

  the poses   each photo's camera displacement along its axis (forward = towards the subject)
              against its zoom (focal / the stored focal) and what the pinhole predicts for
              the subject at z-depth d: d (1 - f / f_photo); their correlation and slope;
  the solve   the twin's RMS reprojection error (px) of the points each photo matched, at the
              solved pose and at the true one; its sparse points' tracks;
  the hull    the share of the masks' visual hull box kept, as config=auto computes it for a
              photo collection (run/subject.py finds the subject's box from the masks and
              scales it to fill ±1; run/from_data.subject_hull carves the box twice that size,
              HULL_VOTE of the photos that see a cell keeping it), through each set of poses;
  SfM         pycolmap on ARC_VIEWS photos of the landmark taken along an arc
              (each through its own zoom and lens, as landmark's), one shared SIMPLE_RADIAL
              camera: how far its camera centres are, after a similarity alignment, from the
              true centres and from the twin's (`colmap_agreement`), on each arc of --arc_seeds.

  python -m nerf_jax.bench.sfm_twin                          # 40 views of 64 px, ~2 minutes
  python -m nerf_jax.bench.sfm_twin --num_views=100 --image_size=100 --arc_seeds=
"""

import dataclasses
import os
import tempfile

import numpy as np
from absl import app, flags

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data import data_settings, loaders, scenes
from nerf_jax.data.scenes import landmark, landmark_sfm
from nerf_jax.run import from_data, photo_zoom, subject
from nerf_jax.samplers import visual_hull

ARC_VIEWS, ARC_SIZE = 12, 256  # the SfM check's photos: 12 of 256 px (SIFT needs the pixels)
ARC_DEGREES = 40.0  # ... along an arc this wide (neighbours share most of what they see)
ARC_DISTANCE = (2.5, 4.5)  # ... this many subject sizes away (log-uniform)
ARC_ELEVATION = (8.0, 25.0)  # ... and this high above the horizon (degrees, uniform)
ARC_STREAM = 0xA2C  # the arc's own draws (see photos.GAIN_STREAM)


def forward_moves(poses, true_poses):
  """float64 [N]: how far each camera float [N, 4, 4] moved from its true one along the true
  viewing direction (-z of the camera; > 0 towards what it looks at)."""
  true_poses = np.asarray(true_poses, np.float64)
  forward = -true_poses[:, :3, 2]
  return np.sum((np.asarray(poses, np.float64)[:, :3, 3] - true_poses[:, :3, 3]) * forward, -1)


def predicted_moves(true_poses, focals, focal, target=(0.0, 0.0, 0.0)):
  """float64 [N]: the move along the axis by which a pinhole of `focal` sees a subject at
  `target` (its z-depth d in each true camera float [N, 4, 4]) as large as a photo of focals
  float [N] does: the subject's scale f / d' = f_photo / d gives d - d' = d (1 - f / f_photo)."""
  true_poses = np.asarray(true_poses, np.float64)
  depth = np.sum((np.asarray(target) - true_poses[:, :3, 3]) * -true_poses[:, :3, 2], -1)
  return depth * (1.0 - focal / np.asarray(focals, np.float64))


def hull_kept(train, fit_zoom=False):
  """(share of the box kept float, the subject's SubjectBox, each photo's focal / the stored
  one float64 [N]): the masks' visual hull of the training views `train` as config=auto carves
  it for a photo collection (module docstring), through the stored camera or, with
  `fit_zoom`, through each photo's focal fitted to its mask first (data.photo_zoom)."""
  box = subject.subject_box(train)
  scale = 1.0 / (subject.MARGIN * float(np.max(box.half)))  # capture's scene_bound -1 -> 1
  moved = train.moved(box.centre, scale)
  extent = from_data.SUBJECT_HULL_EXTENT  # times scene_bound, 1
  if fit_zoom:
    moved = photo_zoom.with_photo_zoom(moved, extent, from_data.HULL_VOTE, moved.pixel_center)
  hull = visual_hull.carve_vote(moved.masks, moved.poses, moved.cameras, extent,
                                from_data.SUBJECT_HULL_CELLS, from_data.HULL_VOTE,
                                moved.pixel_center)
  zooms = np.array([moved.cameras.camera(k)[2][0] for k in range(len(moved))]) / train.focal
  return float(np.mean(hull)), box, zooms


def arc_poses(num_views=ARC_VIEWS, seed=0):
  """float64 [N, 4, 4]: cameras looking at the landmark from azimuths evenly over ARC_DEGREES,
  ARC_DISTANCE (log-uniform) away, ARC_ELEVATION high, drawn with default_rng((seed,
  ARC_STREAM))."""
  rng = np.random.default_rng([seed, ARC_STREAM])
  thetas = np.linspace(0.0, ARC_DEGREES, num_views)
  distances = landmark.SIZE * np.exp(rng.uniform(*np.log(ARC_DISTANCE), num_views))
  phis = rng.uniform(*ARC_ELEVATION, num_views)
  return np.stack([rays_lib.pose_spherical(t, -p, d)
                   for t, p, d in zip(thetas, phis, distances)]).astype(np.float64)


def arc_photos(poses, size, focal, seed=0):
  """The static landmark photographed by cameras float [N, 4, 4], each through its own zoom and
  lens (`landmark.lenses(N, focal, seed)`), no passers-by, neutral look: (rgb float64 [N, S, S,
  3], depth float64 [N, S, S], focals float64 [N], dists float64 [N, 2])."""
  focals, dists = landmark.lenses(len(poses), focal, seed)
  rgb, depth = [], []
  for pose, f, k in zip(poses, focals, dists):
    colour, z, _ = landmark.trace(*landmark.photo_rays(pose, size, size, f, k))
    rgb.append(colour.reshape(size, size, 3))
    depth.append(z.reshape(size, size))
  return np.stack(rgb), np.stack(depth), focals, dists


def colmap_centres(images, focal, folder):
  """(camera centres float64 [M, 3] in COLMAP's frame, index int [M] of the photo each is,
  shared focal float): pycolmap's incremental SfM on photos float [N, S, S, 3] with ONE shared
  SIMPLE_RADIAL camera started at `focal` (refined, with its k1), one thread (COLMAP then
  repeats itself), two-view inlier thresholds low enough for a few hundred SIFT features.
  folder: a scratch folder for the images and the database."""
  import imageio.v3 as iio  # pylint: disable=import-outside-toplevel
  from nerf_jax.data import sfm  # pylint: disable=import-outside-toplevel
  pycolmap = sfm.require_pycolmap()
  pycolmap.logging.minloglevel = 2
  pycolmap.set_random_seed(0)
  image_dir, database = os.path.join(folder, "images"), os.path.join(folder, "database.db")
  os.makedirs(image_dir, exist_ok=True)
  for k, image in enumerate(images):
    iio.imwrite(os.path.join(image_dir, f"{k:03d}.png"),
                (np.clip(image, 0, 1) * 255).round().astype(np.uint8))
  size = images.shape[1]
  reader = pycolmap.ImageReaderOptions()
  reader.camera_model = "SIMPLE_RADIAL"
  reader.camera_params = f"{focal},{size / 2},{size / 2},0"
  extraction = pycolmap.FeatureExtractionOptions()
  extraction.num_threads = 1
  extraction.sift.peak_threshold = 0.002  # the textures' low contrast: a few hundred features
  pycolmap.extract_features(database, image_dir, camera_mode=pycolmap.CameraMode.SINGLE,
                            reader_options=reader, extraction_options=extraction,
                            device=pycolmap.Device.cpu)
  matching = pycolmap.FeatureMatchingOptions()
  matching.num_threads = 1
  pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
  mapping = pycolmap.IncrementalPipelineOptions()
  mapping.num_threads = 1
  mapping.ba_refine_principal_point = False
  mapping.mapper.init_min_num_inliers = 30  # default 100: more than these photos' matches
  mapping.mapper.abs_pose_min_num_inliers = 15
  mapping.min_model_size = 3
  models = pycolmap.incremental_mapping(database, image_dir, os.path.join(folder, "models"),
                                        options=mapping)
  if not models:
    return np.zeros((0, 3)), np.zeros(0, int), float("nan")
  rec = sfm.convert(max(models.values(), key=lambda m: m.num_reg_images()))
  index = np.array([int(os.path.splitext(n)[0]) for n in rec.names])
  return rec.poses[:, :3, 3], index, float(rec.intrinsics[0, 0])


def aligned(source, target):
  """float64 [N, 3]: points `source` float [N, 3] moved by the similarity (scale, rotation,
  translation; least squares, Umeyama) that brings them nearest `target` float [N, 3]."""
  mu_s, mu_t = source.mean(0), target.mean(0)
  cov = (target - mu_t).T @ (source - mu_s) / len(source)
  u, sing, vt = np.linalg.svd(cov)
  sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])  # a rotation, not a reflection
  rot = u @ sign @ vt
  scale = np.trace(np.diag(sing) @ sign) / ((source - mu_s) ** 2).sum(-1).mean()
  return scale * (source - mu_s) @ rot.T + mu_t


def colmap_agreement(size=ARC_SIZE, num_views=ARC_VIEWS, seed=0):
  """{'registered', 'colmap_focal', 'to_true', 'to_twin', 'twin_moved'}: pycolmap's camera
  centres on `arc_photos` (the stored focal: the built-in scenes' at this size), aligned by a
  similarity to the true centres and, apart, to the twin's (each photo solved through the
  stored pinhole from the points it matches, `landmark_sfm`): the mean distance after each
  alignment (scene units; the subject is 1 high), and the mean distance the twin moved its
  cameras from the true ones."""
  focal = scenes.TINY_NERF_FOCAL * size / 100
  poses = arc_poses(num_views, seed)
  rgb, depth, focals, dists = arc_photos(poses, size, focal, seed)
  intrinsics = (focal, focal, 0.5 * size, 0.5 * size)
  twin = []
  for pose, z, f, k in zip(poses, depth, focals, dists):
    points, pixels, _ = landmark_sfm.matched_points(z, pose, f, k, 0.5)
    twin.append(landmark_sfm.solved_pose(points, pixels, pose, intrinsics)[0])
  twin = np.stack(twin)
  with tempfile.TemporaryDirectory() as folder:
    centres, index, colmap_focal = colmap_centres(rgb, focal, folder)
  if len(index) < 3:
    return {"registered": len(index)}
  error = lambda target: float(np.mean(np.linalg.norm(aligned(centres, target) - target, axis=-1)))
  return {"registered": len(index), "colmap_focal": colmap_focal,
          "to_true": error(poses[index, :3, 3]), "to_twin": error(twin[index, :3, 3]),
          "twin_moved": float(np.mean(np.linalg.norm(twin[:, :3, 3] - poses[:, :3, 3], -1)))}


def training_views(scene, num_views, image_size):
  """The training Dataset of built-in `scene` as training loads it (data.num_views,
  data.image_size)."""
  settings = data_settings.DataSettings(scene=scene, num_views=num_views, image_size=image_size)
  return loaders.load_dataset(settings)[0]


SUBJECT_GRID = 64  # the monument-only comparison's grid: a far photo's monument has few cells


def hull_line(name, data, zoom):
  """One line: the masks' hull (`hull_kept`) of the training views `data` through the stored
  camera and through each photo's fitted focal; zoom float64 [N]: the photos' true zooms."""
  share, box, _ = hull_kept(data)
  fitted_share, _, fitted = hull_kept(data, fit_zoom=True)
  return (f"| {name} | {' '.join(f'{h:.2f}' for h in box.half)} | {100 * share:.1f}% | "
          f"{100 * fitted_share:.1f}% | {fitted.min():.2f}-{fitted.max():.2f} | "
          f"{np.corrcoef(np.log(fitted), np.log(zoom))[0, 1]:.2f} |")


def moves_line(name, moved, predicted, zoom, solve):
  """One line: how the camera moves `moved` float64 [N] follow the pinhole's `predicted` ones
  for the photos' zooms float64 [N], and the solve's reprojection errors (`Solve`)."""
  zoomed = zoom > 1.0
  slope = float(np.sum(moved * predicted) / np.sum(predicted * predicted))
  return (f"| {name} | {np.corrcoef(moved, predicted)[0, 1]:.3f} | {slope:.2f} | "
          f"{np.sum(moved[zoomed] > 0)}/{np.sum(zoomed)} | {np.sum(moved[~zoomed] < 0)}/"
          f"{np.sum(~zoomed)} | {int(np.median(solve.num_points))} "
          f"({100 * np.mean(solve.subject_share):.0f}%) | {np.median(solve.rms_px):.2f} / "
          f"{np.max(solve.rms_px):.2f} | {np.median(solve.true_rms_px):.2f} / "
          f"{np.max(solve.true_rms_px):.2f} |")


def tracks_line(twin):
  """One line: the twin's sparse points and tracks (Dataset.points, observations,
  point_errors)."""
  length = np.bincount(twin.observations[:, 1], minlength=len(twin.points))
  lo, mid, hi = np.percentile(length, [5, 50, 95])
  return (f"tracks: {len(twin.points)} points (every {landmark_sfm.TRACK_EVERY}th point a photo "
          f"matched), {len(twin.observations)} observations; seen by {mid:.0f} photos (median; "
          f"5-95%: {lo:.0f}-{hi:.0f}); reprojection error through the twin's cameras median "
          f"{np.median(twin.point_errors):.2f} px (95%: "
          f"{np.percentile(twin.point_errors, 95):.2f} px)")


def report(num_views, image_size, arc_seeds=(0, 1, 2), rows=12):
  """The lines this benchmark prints (module docstring); the SfM check on the arcs drawn with
  `arc_seeds` (none: skipped)."""
  truth = training_views("landmark", num_views, image_size)
  twin = training_views("landmark_sfm", num_views, image_size)
  focals, dists = landmark.lenses(len(truth), truth.focal)
  solve = landmark_sfm.reconstruct(truth, focals, dists)
  alone = landmark_sfm.reconstruct(truth, focals, dists, SUBJECT_GRID, subject_only=True)
  monument = dataclasses.replace(twin, poses=alone.poses.astype(np.float32))
  moved, predicted = forward_moves(twin.poses, truth.poses), predicted_moves(
      truth.poses, focals, truth.focal)
  moved_alone = forward_moves(monument.poses, truth.poses)
  zoom = focals / truth.focal
  depth = predicted / (1.0 - truth.focal / focals)
  lines = [f"landmark vs landmark_sfm: {len(truth)} training photos of {image_size} px "
           f"(data.num_views={num_views}), stored focal {truth.focal:.1f} px, zoom "
           f"{zoom.min():.2f}x-{zoom.max():.2f}x; the twin matches the monument, the ground and "
           f"the façades on a {landmark_sfm.GRID}² grid; 'monument only' matches the monument "
           f"alone on a {SUBJECT_GRID}² grid", "",
           "the poses: each camera's move along its axis (+ towards the subject), the pinhole's "
           "prediction d (1 - f / f_photo)",
           "| photo | zoom | k1 | subject depth d | predicted | twin | monument only |",
           "|---:|---:|---:|---:|---:|---:|---:|"]
  for k in np.argsort(zoom)[np.linspace(0, len(zoom) - 1, min(rows, len(zoom))).astype(int)]:
    lines.append(f"| {k} | {zoom[k]:.2f} | {dists[k, 0]:.2f} | {depth[k]:.2f} | "
                 f"{predicted[k]:+.2f} | {moved[k]:+.2f} | {moved_alone[k]:+.2f} |")
  lines += ["", "| poses | correlation with predicted | slope | zoomed-in moved forward | wide "
            "moved back | points a photo (on the monument) | RMS px solved (median / max) | "
            "RMS px at the true pose |", "|---|---:|---:|---:|---:|---:|---:|---:|",
            moves_line("twin", moved, predicted, zoom, solve),
            moves_line("monument only", moved_alone, predicted, zoom, alone), "",
            tracks_line(twin), "",
            "the hull: the masks' visual hull as config=auto carves it; the share of its box "
            "kept through the stored camera, and through each photo's focal fitted to its mask "
            "(data.photo_zoom: the fitted zooms' range, their correlation with the true zooms "
            "in log)", "| poses | subject's half-extent (from the masks) | kept | kept, fitted "
            "zooms | fitted zooms | correlation |", "|---|---|---:|---:|---:|---:|",
            hull_line("landmark (true)", truth, zoom), hull_line("twin", twin, zoom),
            hull_line("monument only", monument, zoom)]
  if arc_seeds:
    lines += ["", f"SfM: pycolmap on {ARC_VIEWS} photos of {ARC_SIZE} px along a {ARC_DEGREES:g}° "
              "arc, one shared SIMPLE_RADIAL camera (stored focal "
              f"{scenes.TINY_NERF_FOCAL * ARC_SIZE / 100:.0f} px); its camera centres aligned by "
              "a similarity to the true ones and to the twin's, mean distance (the subject is 1 "
              "high)", "| arc draw | registered | to the true | to the twin's | the twin moved "
              "them | its focal |", "|---:|---:|---:|---:|---:|---:|"]
    for seed in arc_seeds:
      found = colmap_agreement(seed=seed)
      if "to_true" not in found:
        lines.append(f"| {seed} | {found['registered']} | | | | |")
        continue
      lines.append(f"| {seed} | {found['registered']} | {found['to_true']:.3f} | "
                   f"{found['to_twin']:.3f} | {found['twin_moved']:.3f} | "
                   f"{found['colmap_focal']:.0f} |")
  return lines


def main(argv=None):
  num_views = flags.DEFINE_integer("num_views", 40, "data.num_views (80% are training photos).")
  image_size = flags.DEFINE_integer("image_size", 64, "data.image_size, pixels.")
  arc_seeds = flags.DEFINE_list("arc_seeds", ["0", "1", "2"], "The SfM check's arcs (~10 s "
                                "each); empty: no SfM check.")

  def run(_):
    from nerf_jax import cli  # pylint: disable=import-outside-toplevel
    seeds = [int(s) for s in arc_seeds.value]
    cli.run_main(lambda: print("\n".join(report(num_views.value, image_size.value, seeds)),
                               flush=True))

  app.run(run, argv=argv)


if __name__ == "__main__":
  main()
