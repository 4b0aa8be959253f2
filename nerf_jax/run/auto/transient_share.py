"""A statistic that tells whether training photos hold transient objects (passers-by, cars):
what `--config=auto` can measure after a short warm-up to switch transient handling on.

After a short warm-up the field shows the static scene and not yet what only one photo shows.
A transient object then leaves, in the photos that hold it, residuals that are:
  * large: far above the mean squared error of all the photos (heavy-tailed);
  * clustered in space: a blob the size of an object, not the thin line of an edge the warm-up
    has not sharpened, nor a lone speck;
  * specific to some photos: a part of the scene the warm-up got wrong is wrong in every photo
    that sees it, so every photo has about the same share of it; a transient is in some photos
    and not others.
Each photo's own look (exposure, white balance) is taken out first: its render is scaled per
channel by the least-squares gain to the photo, so that a bright photo is not a transient.

Names: photos, renders — float [N, H, W, 3], the N training photos and the warm-up's renders
of their cameras; residual — float [N, H, W], each pixel's squared error, averaged over the
channels.
"""

import numpy as np

OUTLIER_FACTOR = 4.0  # an outlier's residual exceeds this many times the photos' mean residual
BOX = 5  # side of the box around an outlier in which ...
CLUSTER_SHARE = 0.6  # ... more than this share of the pixels are outliers: a clustered one
BASELINE_QUANTILE = 0.1  # the cleanest photos' clustered share: every photo has this much


def residuals(photos, renders):
  """Residual float64 [N, H, W] of `photos` against `renders` after each photo's look: the
  render of photo n scaled per channel by g = Σ photo·render / Σ render² (its least-squares
  gain; the sums floored at 1e-12, so a black render gives gain 0, not a division by 0)."""
  photos = np.asarray(photos, np.float64)
  renders = np.asarray(renders, np.float64)
  gain = np.sum(photos * renders, axis=(1, 2)) / np.maximum(np.sum(renders ** 2, axis=(1, 2)),
                                                            1e-12)
  return np.mean((photos - gain[:, None, None, :] * renders) ** 2, axis=-1)


def box_share(mask, size):
  """The share of each size x size box (odd size, centred on each pixel; pixels beyond the
  image count as not in the mask) that is in mask bool [N, H, W]: float64 [N, H, W]."""
  half = size // 2
  padded = np.pad(mask.astype(np.float64), ((0, 0), (half + 1, half), (half + 1, half)))
  table = padded.cumsum(1).cumsum(2)  # summed-area table, a zero row and column in front
  height, width = mask.shape[1:]
  total = (table[:, size:size + height, size:size + width] - table[:, :height, size:size + width]
           - table[:, size:size + height, :width] + table[:, :height, :width])
  return total / (size * size)


def clustered_shares(residual):
  """float64 [N]: the share of each photo's pixels that are clustered outliers: a residual
  above OUTLIER_FACTOR x the mean of all residuals (residual float [N, H, W]), with more than
  CLUSTER_SHARE of the BOX x BOX pixels around it such outliers too."""
  residual = np.asarray(residual, np.float64)
  # max(.., 1e-12): photos the warm-up renders exactly have no outliers, not a 0/0.
  outlier = residual > OUTLIER_FACTOR * max(float(np.mean(residual)), 1e-12)
  clustered = outlier & (box_share(outlier, BOX) > CLUSTER_SHARE)
  return np.mean(clustered, axis=(1, 2))


def transient_share(photos, renders):
  """The statistic: the mean over the photos of the share of their pixels that are clustered
  outliers beyond what the cleanest tenth of them hold (BASELINE_QUANTILE of the shares), a
  float in [0, 1]; near 0 for a static scene, about the transients' share of the pixels for a
  crowd. Also the per-photo shares float64 [N] (`clustered_shares`), for a reason line."""
  shares = clustered_shares(residuals(photos, renders))
  baseline = np.quantile(shares, BASELINE_QUANTILE)
  return float(np.mean(np.maximum(shares - baseline, 0.0))), shares
