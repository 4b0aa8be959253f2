"""Cameras that disagree with their points: each photo's focal and pose refined with the field;
else pose refinement stays off, as nothing in the photos measures a pose error."""

import numpy as np

from nerf_jax.run.auto.rule import Rule, measured, switch_flip

# Cameras that disagree with their points: where one camera is stored for every photo and the
# sparse points' mean reprojection error exceeds this share of the image diagonal, each photo's
# focal and pose are refined with the field (train.intrinsics_refinement, train.pose_refinement)
# in place of the zooms fitted to the masks. landmark_sfm (one focal for a 3x zoom spread): 3.2%
# (4.5 px at 100 px); COLMAP models of real photos: 0.03-0.05% (fern 1.32 px at 4032 px,
# Sacre-Coeur 0.57 px at ~1080 px; at most 4x more against images read at data.factor). On
# landmark_sfm at 600 steps refinement gained 0.59 dB over the fitted zooms without the depth,
# 0.89 with it (docs/photo_collections.md, the levers on the twin).
CAMERA_ERROR_SHARE = 0.005


def camera_effects(dataset, stored_camera, fitted_zooms):
  """({field: value}, line or None): each photo's focal and pose refined with the field in place
  of the zooms fitted to the masks (`fitted_zooms`: the subject rule turned data.photo_zoom on)
  where one camera is stored for every photo (`stored_camera`) and the sparse points' mean
  reprojection error (Dataset.point_errors, pixels) exceeds CAMERA_ERROR_SHARE of the image
  diagonal: the stored camera disagrees with what the photos saw. None where not measured (no
  tracks, a camera per photo, or no fitted zooms): the caller's line stands."""
  errors = dataset.point_errors
  if not (stored_camera and fitted_zooms) or errors is None or not len(errors):
    return {}, None
  share = float(np.nanmean(errors)) / float(np.hypot(dataset.height, dataset.width))
  measured = (f"the sparse points' mean reprojection error is {100 * share:.2g}% of the image "
              f"diagonal ({'>' if share > CAMERA_ERROR_SHARE else '<='} "
              f"{100 * CAMERA_ERROR_SHARE:g}%)")
  if share <= CAMERA_ERROR_SHARE:
    return {}, f"pose refinement: off (the stored camera fits its points: {measured})"
  return ({"data.photo_zoom": False, "train.intrinsics_refinement": True,
           "train.pose_refinement": True},
          f"cameras refined with the field (train.intrinsics_refinement, "
          f"train.pose_refinement; in place of data.photo_zoom): the one stored camera "
          f"disagrees with the photos: {measured}")


@measured
def decide(context):
  """camera_effects of every training view (each through its own camera), the zooms fitted by
  the subject rule; else the user's switch stands (train.pose_refinement)."""
  effects, line = camera_effects(context.photos, context.photos.image_cameras is None,
                                 bool(context.effects.get("data.photo_zoom")))
  if line:
    return effects, [line]
  return {}, ["pose refinement: off (nothing in the photos measures a pose error; "
              "train.pose_refinement=True switches it on)"]


def flip_cameras(result, base, context):
  """The cameras as stored, with the zooms fitted to the masks, where auto refined them with the
  field (camera_effects)."""
  if result.train.intrinsics_refinement:
    return {"train.intrinsics_refinement": False, "train.pose_refinement": False,
            "data.photo_zoom": True}, ""
  return None, "auto did not refine the cameras (no tracks that disagree with one stored camera)"


RULE = Rule("pose_refinement", decide, row="cameras refined, pose refinement",
            fields=("train.pose_refinement", "train.intrinsics_refinement"),
            flips={"cameras": flip_cameras,
                   "pose_refinement": switch_flip("train.pose_refinement")})
