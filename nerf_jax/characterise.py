"""What a capture calls for, read from the capture itself (pure numpy): the measurements and
rules behind `--config=auto` (auto.auto_config applies them).

Each rule looks at the training views (a `Dataset`) and returns a `Decision`: its name, what it
found (True / False), and the measured reason, one line:

  background  the images have opacity with empty pixels: an object on a background;
  forward     every camera looks within FORWARD_CONE_DEGREES of the mean viewing direction:
              a forward-facing capture (NDC rays);
  unbounded   no opacity, cameras around the subject (not forward-facing): the content fills
              every photo out to walls or sky, the case of real captures (the box from the data);
  appearance  photos of nearly the same view (each with its nearest camera) differ in mean
              colour by more than APPEARANCE_LOG_RATIO (log of the ratio, median over pairs):
              per-photo exposure or white balance.

Camera axes are those of rays.py: a camera looks down its -z axis.
"""

import dataclasses

import numpy as np

MIN_CAMERAS = 3  # fewer cameras than this cannot be characterised: the defaults are used
FORWARD_CONE_DEGREES = 30.0  # forward-facing: every view direction within this of their mean
EMPTY_ALPHA, EMPTY_SHARE = 0.01, 0.01  # an object capture: >= 1% of pixels with alpha < 0.01
APPEARANCE_LOG_RATIO = 0.1  # a photo-to-photo colour change of ~10% (0.14 stops) or more


@dataclasses.dataclass(frozen=True)
class Decision:
  name: str  # 'background', 'forward', 'unbounded' or 'appearance'
  found: bool  # whether the capture calls for it
  reason: str  # one line: what was measured


def view_directions(poses):
  """Unit viewing directions float64 [N, 3] of cameras float [N, 4, 4] (their -z axes)."""
  d = -np.asarray(poses, np.float64)[:, :3, 2]
  return d / np.linalg.norm(d, axis=1, keepdims=True)


def cone_degrees(poses):
  """The largest angle in degrees between a camera's viewing direction and their mean."""
  dirs = view_directions(poses)
  mean = dirs.mean(0)
  norm = np.linalg.norm(mean)
  if norm < 1e-9:
    return 180.0
  return float(np.degrees(np.arccos(np.clip(dirs @ (mean / norm), -1.0, 1.0))).max())


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


def decide(dataset):
  """[Decision] of the rules (module docstring), or None when the capture has fewer than
  MIN_CAMERAS cameras."""
  if len(dataset) < MIN_CAMERAS:
    return None
  share = empty_share(dataset)
  background = share is not None and share >= EMPTY_SHARE
  out = [Decision("background", background,
                  "no opacity in the images" if share is None else
                  f"{100 * share:.1f}% of pixels are empty (alpha < {EMPTY_ALPHA})")]
  cone = cone_degrees(dataset.poses)
  forward = cone <= FORWARD_CONE_DEGREES
  out.append(Decision("forward", forward, f"every camera looks within {cone:.1f}° of their "
                      f"mean direction ({'<=' if forward else '>'} {FORWARD_CONE_DEGREES:g}°)"))
  unbounded = not background and not forward
  out.append(Decision("unbounded", unbounded,
                      "the photos have no empty background and the cameras surround the "
                      "subject" if unbounded else
                      "an object on a background" if background else "forward-facing"))
  spread = colour_spread(dataset)
  out.append(Decision("appearance", spread > APPEARANCE_LOG_RATIO,
                      f"neighbouring photos differ in mean colour by {100 * spread:.0f}% "
                      f"(median; {'>' if spread > APPEARANCE_LOG_RATIO else '<='} "
                      f"{100 * APPEARANCE_LOG_RATIO:.0f}%)"))
  return out
