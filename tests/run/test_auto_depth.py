"""auto's depth rule (rules/depth.py): DS-NeRF's loss on where the training views carry the
sparse points' tracks, are at most DEPTH_MAX_VIEWS and the samples lie where the points are
(NDC, a masked subject's photo bounds); nothing decided (and nothing printed) without tracks;
the regret benchmark flips it off."""

import numpy as np

from nerf_jax.bench import regret_plan
from nerf_jax.data.dataset import Dataset
from nerf_jax.run import config_lib
from nerf_jax.run.auto.rules import depth, pose_refinement


def views(count, tracks=True):
  """`count` tiny views; with `tracks`, point p seen in views p and p + 1 (mod count)."""
  poses = np.tile(np.eye(4, dtype=np.float32), (count, 1, 1))
  observations = None
  if tracks:
    observations = np.array([(i, p) for p in range(count) for i in (p, (p + 1) % count)],
                            np.int32)
  return Dataset(np.zeros((count, 4, 4, 3), np.float32), poses, (4.0, 4.0, 2.0, 2.0),
                 points=np.zeros((count, 3), np.float32) if tracks else None,
                 point_errors=np.ones(count, np.float32) if tracks else None,
                 observations=observations)


def test_no_tracks_no_decision_and_no_line():
  assert depth.depth_effects(views(5, tracks=False), "NDC") == ({}, [])


def test_few_views_with_tracks_turn_the_depth_on():
  effects, lines = depth.depth_effects(views(5), "forward-facing: NDC rays")
  assert effects == {"loss.depth.weight": depth.DEPTH_WEIGHT}
  assert len(lines) == 1 and lines[0].startswith("depth from the sparse points' tracks")
  assert "10 keypoints of 5 sparse points in 5 training views" in lines[0]
  assert "forward-facing: NDC rays" in lines[0]


def test_samples_away_from_the_points_leave_it_off():
  effects, lines = depth.depth_effects(views(5), "")
  assert effects == {} and lines[0].startswith("no depth from the tracks")
  assert "without a subject's masks" in lines[0]


def test_more_views_than_measured_leave_it_off():
  count = depth.DEPTH_MAX_VIEWS + 1
  effects, lines = depth.depth_effects(views(count), "NDC")
  assert effects == {}
  assert lines[0].startswith("no depth from the tracks")
  assert f"> {depth.DEPTH_MAX_VIEWS}" in lines[0]
  # The limit itself still counts as few.
  assert depth.depth_effects(views(depth.DEPTH_MAX_VIEWS), "NDC")[0]


def test_the_regret_plan_flips_it_off_only_where_auto_turned_it_on():
  on = config_lib.load("capture")
  on.loss.depth.weight = depth.DEPTH_WEIGHT
  assert regret_plan.FLIPS["depth"](on, None, {}) == ({"loss.depth.weight": 0.0}, "")
  off = config_lib.load("capture")
  overrides, why = regret_plan.FLIPS["depth"](off, None, {})
  assert overrides is None and "off" in why


def with_errors(count, error_px, size=100):
  """`views(count)` of `size` px whose sparse points have reprojection error `error_px`."""
  ds = views(count)
  ds.images = np.zeros((count, size, size, 3), np.float32)
  ds.point_errors = np.full(count, error_px, np.float32)
  return ds


def test_cameras_that_disagree_with_their_points_are_refined():
  diagonal = np.hypot(100, 100)
  over = with_errors(5, 1.01 * pose_refinement.CAMERA_ERROR_SHARE * diagonal)
  effects, line = pose_refinement.camera_effects(over, stored_camera=True, fitted_zooms=True)
  assert effects == {"data.photo_zoom": False, "train.intrinsics_refinement": True,
                     "train.pose_refinement": True}
  assert line.startswith("cameras refined with the field") and "> 0.5%" in line
  under = with_errors(5, 0.99 * pose_refinement.CAMERA_ERROR_SHARE * diagonal)
  effects, line = pose_refinement.camera_effects(under, stored_camera=True, fitted_zooms=True)
  assert effects == {} and line.startswith("pose refinement: off") and "<= 0.5%" in line


def test_cameras_are_not_measured_without_tracks_one_camera_or_fitted_zooms():
  disagreeing = with_errors(5, 50.0)
  assert pose_refinement.camera_effects(disagreeing, stored_camera=False, fitted_zooms=True) == ({}, None)
  assert pose_refinement.camera_effects(disagreeing, stored_camera=True, fitted_zooms=False) == ({}, None)
  assert pose_refinement.camera_effects(views(5, tracks=False), True, True) == ({}, None)


def test_the_regret_plan_flips_the_refined_cameras_back_to_the_fitted_zooms():
  refined = config_lib.load("capture")
  refined.train.intrinsics_refinement = True
  refined.train.pose_refinement = True
  assert regret_plan.FLIPS["cameras"](refined, None, {}) == (
      {"train.intrinsics_refinement": False, "train.pose_refinement": False,
       "data.photo_zoom": True}, "")
  assert regret_plan.FLIPS["cameras"](config_lib.load("capture"), None, {})[0] is None
