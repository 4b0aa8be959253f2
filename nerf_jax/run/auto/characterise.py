"""What a capture calls for, read from the capture itself (numpy; pixels and cameras through
rays.pixel_directions and visual_hull.project): the measurements and rules behind
`--config=auto` (auto.auto_config applies them).

Each rule looks at the training views (a `Dataset`) and returns a `Decision`: its name, what it
found (True / False), and the measured reason, one line:

  background  the images have opacity with empty pixels: an object on a background;
  forward     every camera looks within FORWARD_CONE_DEGREES of the mean viewing direction and
              they stand within FORWARD_DEPTH_SHARE of the near bound of one plane across it:
              a forward-facing capture (NDC rays);
  unbounded   no opacity, cameras around the subject (not forward-facing): the content fills
              every photo out to walls or sky, the case of real captures (the box from the data);
  scales      the cameras' pixel footprints at the scene's centre (`pixel_footprints`: distance
              over focal length) differ by FOOTPRINT_SPREAD or more (max over min): cameras at
              several distances or resolutions, the case for cones (cameras/cones.py).
  appearance  photos of nearly the same view (each with its nearest camera) differ in mean
              colour by more than APPEARANCE_LOG_RATIO (log of the ratio, median over pairs),
              or the photos' focal lengths differ ZOOM_SPREAD times or more (many lenses):
              per-photo exposure or white balance.
  view_dependence  highlights that move between views (`highlight_excess`): a fifth of the
              surface points look more than HIGHLIGHT_LOG_RATIO brighter (log) from two views
              than from most. It needs the views' depth (the built-in scenes, RGB-D data) to
              match points and to tell a highlight from an occluder; without depth it is not
              measured (found None) and the representation's config decides.
  focus       (`focus`, read where auto contracts the space beyond the box) the optical axes
              meet at one point that the median camera sees within asin(FOCUS_SINE) of its
              axis: the cameras look at one subject, and the box is centred on it.

Camera axes are those of rays.py: a camera looks down its -z axis.
"""

import dataclasses
from typing import Optional

import numpy as np

from nerf_jax.cameras import rays
from nerf_jax.samplers import visual_hull

MIN_CAMERAS = 3  # fewer cameras than this cannot be characterised: the defaults are used
FORWARD_CONE_DEGREES = 30.0  # forward-facing: every view direction within this of their mean
FORWARD_DEPTH_SHARE = 0.5  # and the cameras within this share of the near bound of one plane
# across that direction: NDC starts every ray on the near plane (fern: 0.07; ten tourist photos
# of a facade, taken from the steps and from across the square: 9.6)
EMPTY_ALPHA, EMPTY_SHARE = 0.01, 0.01  # an object capture: >= 1% of pixels with alpha < 0.01
APPEARANCE_LOG_RATIO = 0.1  # a photo-to-photo colour change of ~10% (0.14 stops) or more
ZOOM_SPREAD = 1.5  # or focal lengths (over the image's diagonal) that differ this much between
# photos with cameras of their own: many lenses and zooms, a collection taken by many (ten
# tourist photos of Sacre-Coeur: 3.3x; mip-NeRF's multiscale lego: 1x)
HIGHLIGHT_QUANTILE = 0.8  # highlight_excess: of the points, the 20% most lit from some views
HIGHLIGHT_LOG_RATIO = 0.2  # view dependence above this excess, e^0.2 = 1.22x (built-in scenes
#   at 24-100 px: Lambertian <= 0.19, glossy >= 0.21; docs/appearance_and_poses.md)
DEPTH_AGREEMENT = 0.02  # a view sees a point when its own depth there agrees to 2%
OPAQUE = 0.99  # surface points come from pixels at least this opaque (where opacity is known)
HIGHLIGHT_VIEWS, HIGHLIGHT_POINTS = 16, 800  # reference views, and the points picked in each
FOOTPRINT_SPREAD = 2.0  # cones when the cameras' pixel footprints at the centre differ 2x or more
PARALLEL_AXES = 0.05  # focus_point: axes this close to parallel (mean sin^2) meet nowhere
FOCUS_SINE = 0.25  # the cameras look at one point: the median sees it within 14.5° of its axis


@dataclasses.dataclass(frozen=True)
class Decision:
  name: str  # 'background', 'forward', 'unbounded', 'appearance', 'view_dependence', 'scales',
  #   'focus' (`focus`, asked for by auto where the space beyond the box is contracted)
  found: Optional[bool]  # whether the capture calls for it; None: the data cannot tell
  reason: str  # one line: what was measured


def zoom_spread(dataset):
  """The ratio of the largest to the smallest focal length over the image's diagonal among
  `dataset`'s cameras (1 for one camera)."""
  cams = dataset.cameras
  angular = cams.fx / np.hypot(cams.width, cams.height)
  return float(angular.max() / angular.min())


def view_directions(poses):
  """Unit viewing directions float64 [N, 3] of cameras float [N, 4, 4] (their -z axes)."""
  d = -np.asarray(poses, np.float64)[:, :3, 2]
  return d / np.linalg.norm(d, axis=1, keepdims=True)


def mean_direction(poses):
  """float64 [3], the unit mean of the viewing directions of cameras float [N, 4, 4]; None
  where they look every way (the mean is shorter than 1e-9)."""
  mean = view_directions(poses).mean(0)
  norm = np.linalg.norm(mean)
  return None if norm < 1e-9 else mean / norm


def cone_degrees(poses):
  """The largest angle in degrees between a camera's viewing direction and their mean."""
  mean = mean_direction(poses)
  if mean is None:
    return 180.0
  return float(np.degrees(np.arccos(np.clip(view_directions(poses) @ mean, -1.0, 1.0))).max())


def depth_spread(poses):
  """How far apart (max - min) the camera centres of `poses` float [N, 4, 4] stand along their
  mean viewing direction (infinite where they look every way: not near one plane across it)."""
  mean = mean_direction(poses)
  if mean is None:
    return float("inf")
  along = np.asarray(poses, np.float64)[:, :3, 3] @ mean
  return float(along.max() - along.min())


def axes_meet(poses):
  """float64 [3] or None: the point nearest every camera's optical axis (least squares), or
  None where the axes are too close to parallel to meet (mean sin^2 of their angle to the least
  determined direction below PARALLEL_AXES: a forward-facing capture) or meet behind most
  cameras (looking outwards). poses: float [N, 4, 4] camera-to-world."""
  poses = np.asarray(poses, np.float64)
  centres, dirs = poses[:, :3, 3], view_directions(poses)
  projectors = np.eye(3) - dirs[:, :, None] * dirs[:, None, :]  # onto each axis' normal plane
  a = projectors.mean(0)
  b = np.einsum("nij,nj->i", projectors, centres) / len(poses)
  if np.linalg.eigvalsh(a)[0] < PARALLEL_AXES:
    return None
  point = np.linalg.solve(a, b)  # a's eigenvalues >= PARALLEL_AXES > 0: well conditioned
  ahead = np.mean(np.einsum("ni,ni->n", point - centres, dirs) > 0) > 0.5
  return point if ahead else None


def focus_point(poses, near, far):
  """float64 [3]: where the cameras look: `axes_meet`'s point, or where the axes meet nowhere
  the point at depth sqrt(near·far) ahead of the cameras' mean centre along their mean
  direction.

  poses: float [N, 4, 4] camera-to-world. near, far: float > 0, the scene's z-depth bounds.
  """
  point = axes_meet(poses)
  if point is not None:
    return point
  poses = np.asarray(poses, np.float64)
  dirs = view_directions(poses)
  mean_dir = dirs.mean(0) / max(np.linalg.norm(dirs.mean(0)), 1e-9)
  return poses[:, :3, 3].mean(0) + np.sqrt(near * far) * mean_dir


def off_axis_sines(poses, point):
  """float64 [N]: for each camera, the distance of its optical axis from `point` (float [3])
  over its own distance from it, the sine of the angle at which it sees the point off its axis
  (1 for a point beside or behind it)."""
  poses = np.asarray(poses, np.float64)
  to_point = np.asarray(point, np.float64) - poses[:, :3, 3]
  distance = np.linalg.norm(to_point, axis=1)
  along = np.einsum("ni,ni->n", to_point, view_directions(poses))
  # A camera at the point (distance 0) sees it on no axis: sine 1, and no division by 0.
  sine = np.sqrt(np.maximum(distance ** 2 - along ** 2, 0.0)) / np.maximum(distance, 1e-12)
  return np.where((along > 0) & (distance > 1e-12), sine, 1.0)


def focus(poses):
  """Decision 'focus': the cameras all look at one point (nerfstudio's 'focus' centring): their
  axes meet (`axes_meet`) and the median camera sees the point within asin(FOCUS_SINE) of its
  axis (`off_axis_sines`)."""
  point = axes_meet(poses)
  if point is None:
    return Decision("focus", False, "the optical axes meet nowhere ahead of the cameras "
                                    "(parallel or looking outwards)")
  sine = float(np.median(off_axis_sines(poses, point)))
  found = sine <= FOCUS_SINE
  where = ", ".join(f"{v:.3g}" for v in point)
  return Decision("focus", found,
                  f"the optical axes meet at ({where}), {np.degrees(np.arcsin(sine)):.1f}° off "
                  f"the median camera's axis ({'<=' if found else '>'} "
                  f"{np.degrees(np.arcsin(FOCUS_SINE)):.1f}°)")


def pixel_footprints(dataset):
  """float64 [N]: each camera's pixel size in world units at the scene's centre (`focus_point`):
  its distance from there over its focal length (mean of fx, fy)."""
  cameras = dataset.cameras
  poses = np.asarray(dataset.poses, np.float64)
  centre = focus_point(poses, dataset.near, dataset.far)
  distance = np.linalg.norm(poses[:, :3, 3] - centre, axis=1)
  return distance / (0.5 * (cameras.fx + cameras.fy))


def footprint_spread(dataset):
  """Largest over smallest of `pixel_footprints`: 1 for cameras alike, 8 for mip-NeRF's
  multiscale Blender data (4 resolutions an octave apart)."""
  footprints = pixel_footprints(dataset)
  return float(footprints.max() / max(footprints.min(), 1e-12))


def empty_share(dataset):
  """The share of pixels with opacity below EMPTY_ALPHA (None without opacity)."""
  if dataset.accs is None:
    return None
  return float(np.mean(np.asarray(dataset.accs) < EMPTY_ALPHA))


def nearest_cameras(poses):
  """int [N]: for each camera the other one closest to it in centre and direction (distance
  of centres, in units of their spread, plus the angle between directions in radians)."""
  poses = np.asarray(poses, np.float64)
  centres = poses[:, :3, 3]
  spread = max(float(np.linalg.norm(centres - centres.mean(0), axis=1).mean()), 1e-9)
  dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1) / spread
  dirs = view_directions(poses)
  dist = dist + np.arccos(np.clip(dirs @ dirs.T, -1.0, 1.0))
  np.fill_diagonal(dist, np.inf)
  return np.argmin(dist, axis=1)


def colour_spread(dataset):
  """How much photos of nearly the same view differ in exposure and white balance: the median
  over cameras of the change of log mean colour from its nearest camera's (see the code). With
  opacity the means are over the subject (weighted by alpha), so a subject that fills more or
  less of the frame does not count as a change of exposure."""
  images = np.asarray(dataset.images, np.float64).reshape(len(dataset), -1, 3)
  weights = (np.ones(images.shape[:2]) if dataset.accs is None else
             np.asarray(dataset.accs, np.float64).reshape(len(dataset), -1))
  means = (images * weights[..., None]).sum(1) / np.maximum(weights.sum(1), 1e-9)[:, None]
  logs = np.log(means + 1e-3)
  change = logs - logs[nearest_cameras(dataset.poses)]  # [N, 3]
  # Exposure moves every channel one way; a change of what is in view (a red object for a
  # blue one) moves them apart: the brightness part (the channels' mean) and the white-balance
  # part (their spread about it, halved: content changes it too) are counted separately.
  exposure = np.abs(change.mean(axis=1))
  balance = 0.5 * np.abs(change - change.mean(axis=1, keepdims=True)).max(axis=1)
  return float(np.median(np.maximum(exposure, balance)))


def _nanmedian(a, axis):
  """The median of the finite entries of `a` along `axis` (NaN where there are none), without
  numpy's all-NaN warning."""
  a = np.sort(np.moveaxis(a, axis, -1), axis=-1)  # NaNs sort last
  count = np.isfinite(a).sum(-1)
  lo = np.take_along_axis(a, np.maximum(count - 1, 0)[..., None] // 2, -1)[..., 0]
  hi = np.take_along_axis(a, (count // 2)[..., None], -1)[..., 0] if a.shape[-1] else lo
  return np.where(count > 0, 0.5 * (lo + np.where(count > 1, hi, lo)), np.nan)


def _seen_from(dataset, points, log_luminance):
  """float64 [P, N]: the log luminance of each point float64 [P, 3] in each view, NaN where the
  view does not see it (outside the frame, behind it, its own depth there disagrees by more
  than DEPTH_AGREEMENT: an occluder, or not opaque)."""
  num, height, width = log_luminance.shape
  out = np.full((len(points), num), np.nan)
  for j, pose in enumerate(np.asarray(dataset.poses, np.float64)):
    column, row, z = (np.asarray(a, np.float64) for a in visual_hull.project(
        points, pose, dataset.intrinsics, dataset.pixel_center))
    col, row = np.floor(column + 0.5).astype(int), np.floor(row + 0.5).astype(int)
    seen = (z > 1e-9) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    col, row = np.clip(col, 0, width - 1), np.clip(row, 0, height - 1)
    seen &= np.abs(dataset.depths[j][row, col] - z) < DEPTH_AGREEMENT * z
    if dataset.accs is not None:
      seen &= dataset.accs[j][row, col] > OPAQUE
    out[:, j] = np.where(seen, log_luminance[j][row, col], np.nan)
  return out


def highlight_excess(dataset, seed=0):
  """How much brighter some views see the surface than most do: over surface points, the
  HIGHLIGHT_QUANTILE of (second-brightest − median) of a point's log luminance across the
  views that see it; None without depth.

  Points: HIGHLIGHT_POINTS opaque pixels of each of HIGHLIGHT_VIEWS reference views, lifted to
  3D by their depth and looked up in every view that sees them (`_seen_from`; at least 4 such
  views). Each view's median difference from the reference over these points is removed
  first, so a photo's own exposure is not a highlight. A Lambertian point looks the same from
  every view; a highlight lights it in the views near its mirror direction. The second
  brightest, not the brightest, so one mismatched pixel at an edge does not count; a high
  quantile, not the mean, because highlights cover a small part of a scene. float >= 0.
  """
  if dataset.depths is None:
    return None
  images = np.asarray(dataset.images, np.float64)
  num, height, width = images.shape[:3]
  log_luminance = np.log(images.mean(-1) + 0.05)  # +0.05: dark pixels' noise stays small
  poses = np.asarray(dataset.poses, np.float64)
  directions = np.asarray(rays.pixel_directions(height, width, *dataset.intrinsics,
                                                dataset.pixel_center), np.float64)  # z = -1
  rng = np.random.default_rng(seed)
  excess = []
  for ref in np.unique(np.linspace(0, num - 1, min(HIGHLIGHT_VIEWS, num)).round().astype(int)):
    opaque = (np.ones((height, width), bool) if dataset.accs is None else
              np.asarray(dataset.accs[ref]) > OPAQUE)
    candidates = np.flatnonzero(opaque)
    if not len(candidates):
      continue
    pick = rng.choice(candidates, min(HIGHLIGHT_POINTS, len(candidates)), replace=False)
    row, col = np.divmod(pick, width)
    z = np.asarray(dataset.depths[ref], np.float64)[row, col]
    points = poses[ref, :3, 3] + (directions[row, col] * z[:, None]) @ poses[ref, :3, :3].T
    seen = _seen_from(dataset, points, log_luminance)
    gain = _nanmedian(seen - seen[:, ref:ref + 1], axis=0)  # each view's exposure offset
    seen = seen - np.where(np.isfinite(gain), gain, 0.0)
    seen = seen[np.isfinite(seen).sum(1) >= 4]
    second = -np.sort(-np.where(np.isfinite(seen), seen, -np.inf), axis=1)[:, 1]
    excess.append(second - _nanmedian(seen, axis=1))
  excess = np.concatenate(excess) if excess else np.zeros(0)
  return float(np.quantile(excess, HIGHLIGHT_QUANTILE)) if len(excess) else None


def decide(dataset):
  """[Decision] of the rules (module docstring), or None when the capture has fewer than
  MIN_CAMERAS cameras. The scales rule reads every camera; the others read those that share
  image 0's camera (Dataset.one_camera)."""
  if len(dataset) < MIN_CAMERAS:
    return None
  ratio = footprint_spread(dataset)
  scales = Decision("scales", ratio >= FOOTPRINT_SPREAD,
                    f"pixel footprints at the scene's centre differ {ratio:.2f}x between "
                    f"cameras ({'>=' if ratio >= FOOTPRINT_SPREAD else '<'} "
                    f"{FOOTPRINT_SPREAD:g}x)")
  zooms = zoom_spread(dataset)
  dataset = dataset.one_camera()
  if len(dataset) < MIN_CAMERAS:
    return None
  share = empty_share(dataset)
  background = share is not None and share >= EMPTY_SHARE
  out = [Decision("background", background,
                  "no opacity in the images" if share is None else
                  f"{100 * share:.1f}% of pixels are empty (alpha < {EMPTY_ALPHA})")]
  cone = cone_degrees(dataset.poses)
  within = cone <= FORWARD_CONE_DEGREES
  apart = depth_spread(dataset.poses) / max(float(dataset.near), 1e-9)
  forward = within and apart <= FORWARD_DEPTH_SHARE
  reason = (f"every camera looks within {cone:.1f}° of their mean direction "
            f"({'<=' if within else '>'} {FORWARD_CONE_DEGREES:g}°)")
  if within and not forward:
    reason += (f", but the cameras stand {apart:.2f}x the near bound apart along it (> "
               f"{FORWARD_DEPTH_SHARE:g}x): NDC rays need them near one plane")
  out.append(Decision("forward", forward, reason))
  unbounded = not background and not forward
  out.append(Decision("unbounded", unbounded,
                      "the photos have no empty background and the cameras surround the "
                      "subject" if unbounded else
                      "an object on a background" if background else "forward-facing"))
  spread = colour_spread(dataset)
  looks = spread > APPEARANCE_LOG_RATIO
  reason = (f"neighbouring photos differ in mean colour by {100 * spread:.0f}% (median; "
            f"{'>' if looks else '<='} {100 * APPEARANCE_LOG_RATIO:.0f}%)")
  if not looks and zooms >= ZOOM_SPREAD:
    reason += (f", but their focal lengths differ {zooms:.2f}x (>= {ZOOM_SPREAD:g}x): many "
               "lenses and zooms, a collection taken by many")
  out.append(Decision("appearance", looks or zooms >= ZOOM_SPREAD, reason))
  excess = highlight_excess(dataset)
  if excess is None:
    out.append(Decision("view_dependence", None, "not measured: the views have no depth to "
                        "match their points"))
  else:
    lit = excess > HIGHLIGHT_LOG_RATIO
    out.append(Decision("view_dependence", lit,
                        f"a fifth of the surface points look {np.exp(excess):.2f}x brighter "
                        f"from two views than from most ({'>' if lit else '<='} "
                        f"{np.exp(HIGHLIGHT_LOG_RATIO):.2f}x)"))
  return out + [scales]
