"""Each photo's zoom from its mask: a collection's focal lengths recovered before the first step.

An LLFF file made from a shared COLMAP camera stores one focal length for photos taken at many
zooms. Where masks keep the subject (run/subject.py), the masks' hull (samplers/visual_hull.py)
is the subject's shape seen from every photo at once; seen through the right focal, it covers
the photo's mask. For each training photo the focal scale about the principal point whose
projection of the hull agrees best with the mask (intersection over union, searched on a
log-spaced grid) is that photo's zoom; the hull is then carved again through the found cameras.
The scales are divided by their median, as the stored focal is one for all the photos (COLMAP's
shared camera fits the typical photo): a hull carved through wrong focals is too large, which
biases every scale alike. A photo whose mask the hull's projection meets at no scale (its pose
or its mask contradicts the other photos) says nothing of its zoom: it keeps the stored focal,
and one line names it.

Names: dataset: the training Dataset (one image size; `masks` keep the subject, the world
scaled so the subject fills [-bound, bound]^3: data.subject); pixel_center: float (`cameras.rays`).
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.samplers import occupancy, visual_hull

LOG_SCALES = np.linspace(-1.2, 1.2, 31)  # the focal scales searched first: 0.30x to 3.3x, 8% apart
FINE_STEPS = np.linspace(-0.08, 0.08, 9)  # then about the best of those, 2% apart
ROUNDS = 2  # carve, fit; carve through the fitted cameras, fit again
FIT_CELLS = 64  # the hull's cells per side for the fit (48 leaves a 0.05 bias on the test's ball)


def hull_points(dataset, cameras, bound, vote, pixel_center):
  """float64 [K, 3]: the centres of the cells kept by the masks' vote (visual_hull.carve_vote
  with `vote`, a share) seen through `cameras`, on FIT_CELLS^3 cells over [-bound, bound]^3."""
  hull = visual_hull.carve_vote(dataset.masks, dataset.poses, cameras, bound, FIT_CELLS, vote,
                                pixel_center)
  centres = np.asarray(occupancy.cell_centres(FIT_CELLS, bound), np.float64).reshape(-1, 3)
  return centres[np.asarray(hull).reshape(-1) > 0]


# visual_hull.pixels_seen compiled once per image size (the intrinsics an array: one program
# for every scale and photo; eagerly it took 2.3x as long on landmark)
_pixels_seen = jax.jit(visual_hull.pixels_seen, static_argnums=(3, 4, 5))


def overlap(points, pose, camera, mask, log_scales, pixel_center):
  """float64 [S]: for each focal scale exp(log_scales) float [S], the intersection over union
  of the pixels `points` float [K, 3] fall in, through `camera` ((height, width, (fx, fy, cx,
  cy))) with its focal lengths scaled (about the principal point), and the kept pixels of
  `mask` float [H, W]."""
  height, width, (fx, fy, cx, cy) = camera
  kept = np.asarray(mask) > 0
  points, pose = jnp.asarray(points, jnp.float32), jnp.asarray(pose, jnp.float32)  # sent once
  scores = np.zeros(len(log_scales))
  for n, scale in enumerate(np.exp(log_scales)):
    j, i, seen = (np.asarray(a) for a in _pixels_seen(
        points, pose, np.array([scale * fx, scale * fy, cx, cy]), height, width, pixel_center))
    covered = np.zeros((height, width), bool)
    covered[j[seen], i[seen]] = True
    scores[n] = np.sum(covered & kept) / max(np.sum(covered | kept), 1)
  return scores


def best_scale(points, pose, camera, mask, pixel_center):
  """float: the log focal scale of `camera` whose projection of `points` agrees best with
  `mask` (`overlap`): the best of LOG_SCALES, then of FINE_STEPS about it; None where none of
  LOG_SCALES' projections meets the mask (no scale is better than another)."""
  scores = overlap(points, pose, camera, mask, LOG_SCALES, pixel_center)
  if not scores.max() > 0:
    return None
  fine = LOG_SCALES[np.argmax(scores)] + FINE_STEPS
  return float(fine[np.argmax(overlap(points, pose, camera, mask, fine, pixel_center))])


def fit_zooms(dataset, bound, vote, pixel_center):
  """(float64 [N], int [M]): each training photo's log focal scale against the stored camera
  (median 0 over the photos fitted), after ROUNDS rounds of carving the masks' hull over
  [-bound, bound]^3 and fitting each photo's scale to its mask (module docstring); and the
  photos whose mask the hull's projection meets at no scale in some round (a pose or a mask
  that the others contradict), which keep the stored focal (log scale 0)."""
  cameras, logs = dataset.cameras, np.zeros(len(dataset))
  missed = np.zeros(len(dataset), bool)
  for _ in range(ROUNDS):
    points = hull_points(dataset, cameras, bound, vote, pixel_center)
    found = [best_scale(points, pose, cameras.camera(k), dataset.masks[k], pixel_center)
             for k, pose in enumerate(np.asarray(dataset.poses, np.float64))]
    missed |= np.array([f is None for f in found])
    logs = np.where(missed, 0.0, logs + np.array([f or 0.0 for f in found]))
    if not missed.all():
      logs[~missed] -= np.median(logs[~missed])
    cameras = scaled(dataset.cameras, logs)
  return logs, np.flatnonzero(missed)


def scaled(cameras, log_scales):
  """Cameras `cameras` with each one's focal lengths times exp(log_scales[k]) (float [N])."""
  factor = np.exp(np.asarray(log_scales, np.float64))
  return dataclasses.replace(cameras, fx=cameras.fx * factor, fy=cameras.fy * factor)


def with_photo_zoom(dataset, bound, vote, pixel_center):
  """`dataset` with a camera per photo (`image_cameras`), each focal scaled by its photo's
  fitted zoom (`fit_zooms`), and one line saying their spread; one more naming the photos that
  keep the stored focal, where the hull misses their masks."""
  logs, missed = fit_zooms(dataset, bound, vote, pixel_center)
  print(f"photo zoom: each training photo's focal fitted to its mask against the masks' hull: "
        f"x{np.exp(logs.min()):.2f} to x{np.exp(logs.max()):.2f} of the stored "
        f"{dataset.focal:.4g} px (median x1; data.photo_zoom)", flush=True)
  if len(missed):
    print(f"photo zoom: training photo{'s' * (len(missed) > 1)} "
          f"{', '.join(str(k) for k in missed)} keep{'s' * (len(missed) == 1)} the stored "
          f"focal: the masks' hull meets {'their masks' if len(missed) > 1 else 'its mask'} "
          "at no zoom (a pose or a mask the other photos contradict)", flush=True)
  return dataclasses.replace(dataset, image_cameras=scaled(dataset.cameras, logs))
