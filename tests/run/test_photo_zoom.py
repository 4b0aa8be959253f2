"""Each photo's zoom recovered from its mask (run/photo_zoom.py): a ball photographed at known
zooms through one stored focal, its masks cast ray by ray in the test."""

import dataclasses

import numpy as np
import pytest

from nerf_jax.cameras import rays
from nerf_jax.data.dataset import Dataset
from nerf_jax.run import photo_zoom

SIZE, FOCAL, RADIUS = 64, 100.0, 0.4


def ball_mask(pose, focal):
  """float32 [SIZE, SIZE]: 1 where the pixel's ray (pinhole `focal`, centred) meets the ball of
  RADIUS at the origin: the ray's distance to the centre, written out here."""
  i, j = np.meshgrid(np.arange(SIZE) + 0.5, np.arange(SIZE) + 0.5)
  local = np.stack([(i - SIZE / 2) / focal, -(j - SIZE / 2) / focal, -np.ones_like(i)], -1)
  d = local @ np.asarray(pose, np.float64)[:3, :3].T
  d /= np.linalg.norm(d, axis=-1, keepdims=True)
  o = np.asarray(pose, np.float64)[:3, 3]
  along = -(d @ o)  # the ray's parameter nearest the centre (in front where > 0)
  miss = np.linalg.norm(o + along[..., None] * d, axis=-1)
  return ((miss < RADIUS) & (along > 0)).astype(np.float32)


def collection(num=24, seed=0):
  """(Dataset with one stored focal, true log zooms float64 [num]): the ball's masks through
  each photo's true focal FOCAL * exp(zoom), zooms spread 2x with median 0."""
  rng = np.random.default_rng(seed)
  zooms = rng.permutation(np.linspace(-0.35, 0.35, num))
  poses = np.stack([rays.pose_spherical(t, -p, r) for t, p, r in
                    zip(rng.uniform(0, 360, num), rng.uniform(5, 40, num),
                        rng.uniform(2.5, 5.0, num))]).astype(np.float32)
  masks = np.stack([ball_mask(p, FOCAL * np.exp(z)) for p, z in zip(poses, zooms)])
  images = np.repeat(masks[..., None], 3, -1)
  data = Dataset(images, poses, (FOCAL, FOCAL, SIZE / 2, SIZE / 2), masks=masks)
  return data, zooms


def test_each_photos_zoom_is_recovered_from_its_mask():
  data, zooms = collection()
  found, missed = photo_zoom.fit_zooms(data, bound=1.0, vote=0.6, pixel_center=0.5)
  assert len(missed) == 0
  assert np.median(found) == pytest.approx(0.0, abs=1e-9)  # the stored focal is the median
  error = np.sqrt(np.mean((found - zooms) ** 2))
  assert error < 0.05, (error, np.sqrt(np.mean(zooms ** 2)))  # the stored focal's: 0.21
  assert np.corrcoef(found, zooms)[0, 1] > 0.97


def test_the_found_cameras_replace_the_stored_one():
  data, zooms = collection(num=12, seed=1)
  zoomed = photo_zoom.with_photo_zoom(data, bound=1.0, vote=0.6, pixel_center=0.5)
  assert zoomed.image_cameras is not None and len(zoomed) == len(data)
  fitted = np.log(zoomed.cameras.fx / FOCAL)
  np.testing.assert_allclose(zoomed.cameras.fy, zoomed.cameras.fx)
  np.testing.assert_allclose(zoomed.cameras.cx, SIZE / 2)
  assert np.sqrt(np.mean((fitted - zooms) ** 2)) < 0.06


def test_a_photo_through_its_true_focal_scores_best_at_scale_one():
  data, zooms = collection(num=12, seed=2)
  points = np.stack(np.meshgrid(*[np.linspace(-0.35, 0.35, 15)] * 3, indexing="ij"), -1)
  points = points.reshape(-1, 3)[np.linalg.norm(points.reshape(-1, 3), axis=-1) < RADIUS]
  camera = (SIZE, SIZE, (FOCAL * np.exp(zooms[0]),) * 2 + (SIZE / 2, SIZE / 2))
  scores = photo_zoom.overlap(points, data.poses[0], camera, data.masks[0],
                              photo_zoom.LOG_SCALES, 0.5)
  assert abs(photo_zoom.LOG_SCALES[np.argmax(scores)]) <= 0.04  # 0.08 apart: the grid point 0


def test_a_photo_the_hull_never_meets_keeps_the_stored_focal(capsys):
  # Photo 0 posed looking away from the ball (a pose the others contradict): no zoom projects
  # the hull onto its mask, so none is better than another; it keeps the stored focal, one line
  # names it, and the others are fitted as before (their median the stored focal).
  data, zooms = collection(num=16, seed=3)
  poses = np.array(data.poses)
  poses[0, :3, :3] = poses[0, :3, :3] @ np.diag([-1.0, 1.0, -1.0])  # turned about its y axis
  data = dataclasses.replace(data, poses=poses)
  found, missed = photo_zoom.fit_zooms(data, bound=1.0, vote=0.6, pixel_center=0.5)
  assert list(missed) == [0] and found[0] == 0.0
  others = zooms[1:] - np.median(zooms[1:])
  assert np.sqrt(np.mean((found[1:] - others) ** 2)) < 0.06  # as 12 photos do (above)
  zoomed = photo_zoom.with_photo_zoom(data, bound=1.0, vote=0.6, pixel_center=0.5)
  assert zoomed.cameras.fx[0] == FOCAL
  lines = capsys.readouterr().out.splitlines()
  assert lines[-1].startswith("photo zoom: training photo 0 keeps the stored focal")
