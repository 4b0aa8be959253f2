"""The sparse points' tracks (nerf_jax.data.colmap_model's reader, Dataset.observations, and
train_batches.Keypoints): a COLMAP model written by pycolmap with the built-in 'diffuse' scene's
cameras, each image's keypoints the points' exact projections, read back and compared with what
was written; loaded as a COLMAP folder, beside transforms.json and beside an LLFF folder, each
keypoint projected through the cameras as trained must land on its 2D point and its ray must
pass through its 3D point."""

import json
import os

import imageio.v3 as iio
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data import colmap, colmap_model, llff, nerfstudio, scenes
from nerf_jax.data.dataset import Dataset
from nerf_jax.train import train_batches
from tests.helpers import assert_data_error, load_data, requires_pycolmap

HEIGHT, WIDTH, VIEWS, POINTS = 20, 28, 8, 60
GL_TO_CV = np.diag([1.0, -1.0, -1.0])  # camera axes: OpenGL (y up, z back) <-> OpenCV


def _cam_from_world(c2w):
  """float64 [3, 4], COLMAP's world-to-camera (OpenCV axes) of an OpenGL camera-to-world."""
  rot = np.asarray(c2w, np.float64)[:3, :3] @ GL_TO_CV
  return np.concatenate([rot.T, -rot.T @ np.asarray(c2w, np.float64)[:3, 3:4]], axis=1)


def _project(c2w, intrinsics, points):
  """(xy float64 [P, 2] in COLMAP's pixel convention, z-depth float64 [P]) of world points."""
  fx, fy, cx, cy = intrinsics
  cam = points @ _cam_from_world(c2w)[:, :3].T + _cam_from_world(c2w)[:, 3]
  return np.stack([fx * cam[:, 0] / cam[:, 2] + cx, fy * cam[:, 1] / cam[:, 2] + cy], -1), cam[:, 2]


def tracked_scene(seed=0, views=VIEWS, pose_seed=0):
  """(truth Dataset, points float64 [P, 3], errors float64 [P], model): the 'diffuse' scene's
  views (cameras drawn from pose_seed) and a pycolmap.Reconstruction of its cameras (one
  PINHOLE; image k named as export_llff names it, id 100 - k: ids unlike the names' order) whose
  points are `points` (point p has id p + 1), each image's keypoints their exact projections
  where in front of it and inside it (and two keypoints of no point), each point's track those
  images, its error drawn."""
  import pycolmap  # pylint: disable=import-outside-toplevel
  truth = scenes.make_dataset("diffuse", num_views=views, height=HEIGHT, width=WIDTH,
                              seed=pose_seed)
  rng = np.random.default_rng(seed)
  points = rng.uniform(-1.0, 1.0, (POINTS, 3)) * [1.0, 0.6, 0.8]
  errors = rng.uniform(0.2, 2.0, POINTS)
  fx, fy, cx, cy = truth.intrinsics
  shift = 0.5 - truth.pixel_center  # COLMAP's pixel k spans [k, k + 1): its centre is k + 0.5
  intrinsics = (fx, fy, cx + shift, cy + shift)
  model = pycolmap.Reconstruction()
  model.add_camera_with_trivial_rig(pycolmap.Camera(
      model="PINHOLE", width=WIDTH, height=HEIGHT, params=np.array(intrinsics), camera_id=1))
  tracks = [[] for _ in points]
  for k, c2w in enumerate(truth.poses):
    xy, depth = _project(c2w, intrinsics, points)
    seen = np.flatnonzero((depth > 0) & (xy[:, 0] >= 0) & (xy[:, 0] < WIDTH) & (xy[:, 1] >= 0)
                          & (xy[:, 1] < HEIGHT))
    keypoints = np.concatenate([[[1.5, 2.5]], xy[seen], [[3.0, 4.0]]])  # two of no point
    image_id = 100 - k
    model.add_image_with_trivial_frame(
        pycolmap.Image(name=f"{k:03d}.png", keypoints=keypoints, camera_id=1,
                       image_id=image_id), pycolmap.Rigid3d(_cam_from_world(c2w)))
    for index, p in enumerate(seen):
      tracks[p].append((image_id, index + 1))
  for p, (xyz, track) in enumerate(zip(points, tracks)):
    elements = pycolmap.Track()
    for image_id, index in track:
      elements.add_element(image_id, index)
    point_id = model.add_point3D(xyz, elements, np.array([p % 256, 7, 9], np.uint8))
    assert point_id == p + 1
    model.point3D(point_id).error = errors[p]
  return truth, points, errors, model


def _write(model, folder, binary):
  os.makedirs(folder, exist_ok=True)
  (model.write if binary else model.write_text)(folder)


@requires_pycolmap
@pytest.mark.parametrize("binary", [True, False], ids=["bin", "txt"])
def test_every_observation_and_error_pycolmap_wrote_is_read(tmp_path, binary):
  _, _, errors, model = tracked_scene()
  folder = str(tmp_path / "sparse" / "0")
  _write(model, folder, binary)
  _, images_file, points_file = colmap_model.model_files(folder)
  keypoints, images = colmap_model.read_keypoints(images_file), colmap_model.read_images(images_file)
  assert set(keypoints) == set(images) == set(model.images)
  for image_id, image in model.images.items():
    xy, ids = keypoints[image_id]
    assert images[image_id][3] == image.name
    np.testing.assert_allclose(xy, [p.xy for p in image.points2D], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(ids, [p.point3D_id if p.has_point3D() else -1
                                        for p in image.points2D])
    assert ids[0] == ids[-1] == -1 and np.all(ids[1:-1] >= 0)
  sparse = colmap_model.read_sparse_points(points_file)
  assert len(sparse.ids) == model.num_points3D() == POINTS
  for k, point_id in enumerate(sparse.ids):
    point = model.point3D(int(point_id))
    np.testing.assert_allclose(sparse.xyz[k], point.xyz, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(sparse.rgb[k], point.color)
    np.testing.assert_allclose(sparse.errors[k], point.error, rtol=1e-12)
    in_track = sparse.track_points == k
    assert sorted(zip(sparse.track_images[in_track].tolist(),
                      sparse.track_points2d[in_track].tolist())) == sorted(
        (e.image_id, e.point2D_idx) for e in point.track.elements)
    # Both sides agree: each track element's 2D point names this point.
    for image_id, index in zip(sparse.track_images[in_track], sparse.track_points2d[in_track]):
      assert keypoints[int(image_id)][1][index] == point_id
  np.testing.assert_allclose(np.sort(sparse.errors), np.sort(errors), rtol=1e-12)
  xyz, rgb = colmap_model.read_points(points_file)  # the old reader's form is kept
  np.testing.assert_array_equal(xyz, sparse.xyz)
  np.testing.assert_array_equal(rgb, sparse.rgb)


def test_malformed_tracks_are_one_line_errors(tmp_path):
  points = tmp_path / "points3D.txt"
  points.write_text("1 0 0 1 1 2 3 0.5 4\n")  # a track element without its 2D point
  assert_data_error([str(points), "line 1", "TRACK"], colmap_model.read_sparse_points, str(points))
  points.write_text("1 0 0 1 1 2 3 x 4 0\n")
  assert_data_error([str(points), "line 1", "ERROR"], colmap_model.read_sparse_points, str(points))
  images = tmp_path / "images.txt"
  images.write_text("1 1 0 0 0 0 0 0 1 a.png\n1.5 2.5\n")
  assert_data_error([str(images), "line 2", "POINT3D_ID"], colmap_model.read_keypoints, str(images))
  binary = tmp_path / "images.bin"
  binary.write_bytes(np.array([1], "<u8").tobytes() + np.array([1], "<i4").tobytes() +
                     np.zeros(7).tobytes() + np.array([1], "<i4").tobytes() + b"a.png\0" +
                     np.array([3], "<u8").tobytes() + bytes(24))  # 1 of 3 points
  assert_data_error([str(binary), "truncated"], colmap_model.read_keypoints, str(binary))


def _file_order(folder):
  """int64 [P]: the index into tracked_scene's points (id - 1) of each point of the model in
  `folder`, in its file's order (the Dataset's)."""
  return colmap_model.read_sparse_points(colmap_model.model_files(folder)[2]).ids - 1


def _tracks_of(model, image_ids, order):
  """{(image index, point index)}: the model's tracks, image index k of image id image_ids[k],
  point index the point's place in the file (order: `_file_order`)."""
  order = {int(p) + 1: k for k, p in enumerate(order)}
  index = {image_id: k for k, image_id in enumerate(image_ids)}
  return {(index[e.image_id], order[point_id]) for point_id, point in model.points3D.items()
          for e in point.track.elements if e.image_id in index}


def _keypoints(dataset, camera=None):
  """train_batches.Keypoints of `dataset`'s observations through its own cameras (a shared
  camera's rays as builders.make_train_data makes them; camera: its (near, far, use_ndc))."""
  near, far, ndc = camera or (dataset.near, dataset.far, False)
  cam = (dataset.height, dataset.width, dataset.intrinsics, near, far, dataset.pixel_center, ndc)
  data = train_batches.make_train_data(dataset, cam, np.zeros(3, np.float32), keypoints=True)
  return data, data.keypoints


def _check_keypoints(dataset, model, image_ids, order, offset):
  """Each keypoint of `dataset` lands on its 2D point of `model` (COLMAP's pixel convention, as
  `at` + `offset`), and the ray through it passes through its 3D point at its t (order:
  `_file_order`)."""
  data, kp = _keypoints(dataset)
  order = {int(p) + 1: k for k, p in enumerate(order)}
  wanted = {}
  for k, image_id in enumerate(image_ids):
    for point2d in model.image(image_id).points2D:
      if point2d.has_point3D():
        wanted[(k, order[point2d.point3D_id])] = point2d.xy
  obs = np.asarray(dataset.observations)
  image, at = np.asarray(kp.image), np.asarray(kp.at, np.float64)
  assert len(kp) == len(obs) and np.array_equal(image, obs[:, 0])  # every one in view: all kept
  want = np.array([wanted[(int(i), int(p))] for i, p in obs])
  np.testing.assert_allclose(at + offset, want, rtol=0, atol=2e-3)
  rays = train_batches.keypoint_rays(data, kp)
  hit = np.asarray(rays.origins) + np.asarray(kp.t)[:, None] * np.asarray(rays.directions)
  np.testing.assert_allclose(hit, dataset.points[obs[:, 1]], rtol=0, atol=1e-4)


@requires_pycolmap
@pytest.mark.parametrize("binary", [True, False], ids=["bin", "txt"])
def test_colmap_folder_observations_land_on_their_keypoints(tmp_path, binary):
  truth, points, errors, model = tracked_scene()
  folder = str(tmp_path / "scene")
  llff.export_llff(truth, folder)  # images/000.png ...
  os.remove(os.path.join(folder, "poses_bounds.npy"))
  _write(model, os.path.join(folder, "sparse", "0"), binary)
  dataset, names = colmap.load(folder)
  ids = [100 - int(n[:3]) for n in names]
  order = _file_order(os.path.join(folder, "sparse", "0"))
  tracks = _tracks_of(model, ids, order)
  assert {tuple(o) for o in dataset.observations.tolist()} == tracks
  assert len(dataset.observations) == len(tracks)  # each pair once
  np.testing.assert_allclose(dataset.point_errors, errors[order], rtol=1e-6)
  # The loaded world is a similarity of the model's: the keypoints through the loaded cameras
  # (the COLMAP loader's rays pass through pixel centres with pixel_center 0 and cx - 0.5).
  assert dataset.pixel_center == 0.0
  _check_keypoints(dataset, model, ids, order, offset=0.5)
  # data.factor: the images and the cameras halved, the keypoints with them.
  half, names = colmap.load(folder, factor=2)
  data, kp = _keypoints(half)
  full = _keypoints(dataset)[1]
  np.testing.assert_allclose((np.asarray(kp.at) + 0.5) * 2, np.asarray(full.at) + 0.5,
                             atol=2e-3)
  np.testing.assert_allclose(kp.t, full.t, rtol=1e-5)
  # The split keeps each image's observations, re-indexed.
  train, test = load_data({"path": folder})
  for part, indices in ((test, [0]), (train, list(range(1, VIEWS)))):
    want = {(indices.index(i), p) for i, p in dataset.observations.tolist() if i in indices}
    assert {tuple(o) for o in part.observations.tolist()} == want
  np.testing.assert_array_equal(train.point_errors, dataset.point_errors)


@requires_pycolmap
def test_transforms_json_with_the_model_beside_it_gets_its_tracks(tmp_path):
  truth, points, errors, model = tracked_scene()
  # transforms.json in a frame of its own: a similarity of COLMAP's (as nerf-process writes).
  angle, scale, offset = 0.7, 0.37, np.array([0.3, -0.2, 0.5])
  rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                  [0, 0, 1]])
  moved = np.array(truth.poses, np.float64)
  moved[:, :3, :3] = rot @ moved[:, :3, :3]
  moved[:, :3, 3] = scale * moved[:, :3, 3] @ rot.T + offset
  fx, fy, cx, cy = truth.intrinsics
  (tmp_path / "images").mkdir()
  frames = []
  for k, image in enumerate(truth.images):
    iio.imwrite(tmp_path / "images" / f"{k:03d}.png", (image * 255).round().astype(np.uint8))
    frames.append({"file_path": f"images/{k:03d}.png", "transform_matrix": moved[k].tolist()})
  meta = {"fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": WIDTH, "h": HEIGHT,
          "nerf_jax_normalized": True, "near": 0.5, "far": 3.0, "frames": frames}
  (tmp_path / "transforms.json").write_text(json.dumps(meta))
  _write(model, str(tmp_path / "colmap" / "sparse" / "0"), binary=True)
  dataset, names, _ = nerfstudio.load(str(tmp_path))
  ids = [100 - int(os.path.basename(n)[:3]) for n in names]
  order = _file_order(str(tmp_path / "colmap" / "sparse" / "0"))
  assert {tuple(o) for o in dataset.observations.tolist()} == _tracks_of(model, ids, order)
  np.testing.assert_allclose(dataset.points, scale * points[order] @ rot.T + offset, atol=1e-5)
  np.testing.assert_allclose(dataset.point_errors, errors[order], rtol=1e-6)
  _check_keypoints(dataset, model, ids, order, offset=0.5)
  # A model of other cameras under the same names: its tracks are left out, with a line.
  _write(tracked_scene(pose_seed=1)[3], str(tmp_path / "colmap" / "sparse" / "0"), binary=True)
  dataset, _, _ = nerfstudio.load(str(tmp_path))
  assert dataset.observations is None and dataset.point_errors is None
  assert dataset.points is None  # as without the model: the file names no ply


@requires_pycolmap
def test_llff_folder_with_sparse_0_gets_its_tracks_moved_with_the_poses(tmp_path):
  truth, points, errors, model = tracked_scene()
  folder = str(tmp_path / "llff")
  llff.export_llff(truth, folder)
  _write(model, os.path.join(folder, "sparse", "0"), binary=False)
  order = _file_order(os.path.join(folder, "sparse", "0"))
  plain = llff.load_llff(folder)  # the file's frame: COLMAP's here
  np.testing.assert_allclose(plain.points, points[order], atol=1e-5)
  dataset = llff.load_llff(folder, bd_factor=0.75, recenter=True)
  ids = [100 - k for k in range(VIEWS)]
  assert {tuple(o) for o in dataset.observations.tolist()} == _tracks_of(model, ids, order)
  np.testing.assert_allclose(dataset.point_errors, errors[order], rtol=1e-6)
  # LLFF's rays pass through pixel centres (pixel_center 0.5, cx = W / 2): COLMAP's x is ours.
  _check_keypoints(dataset, model, ids, order, offset=0.5)
  # In NDC (the near plane z = -1 after bd_factor): the NDC ray reaches the point's NDC image
  # at its t = 1 - 1 / depth.
  data, kp = _keypoints(dataset, camera=(0.0, 1.0, True))
  obs = np.asarray(dataset.observations)
  inside = np.asarray(data.keypoints.image)
  p = dataset.points[obs[:, 1]].astype(np.float64)
  kept = -p[:, 2] > 1.0
  assert len(kp) == kept.sum() and np.array_equal(inside, obs[kept, 0])
  p = p[kept]
  np.testing.assert_allclose(kp.t, 1.0 - 1.0 / -p[:, 2], atol=1e-6)
  np.testing.assert_allclose(kp.scale, 1.0 / -p[:, 2], atol=1e-6)
  rays = train_batches.keypoint_rays(data, kp)
  fx, fy = dataset.intrinsics[:2]
  ndc = np.stack([-(2 * fx / WIDTH) * p[:, 0] / p[:, 2], -(2 * fy / HEIGHT) * p[:, 1] / p[:, 2],
                  1 + 2.0 / p[:, 2]], -1)
  hit = np.asarray(rays.origins) + np.asarray(kp.t)[:, None] * np.asarray(rays.directions)
  np.testing.assert_allclose(hit, ndc, atol=1e-4)


def _toy(masks=None, image_cameras=None):
  """A Dataset of 3 views of 8 x 10 through one pinhole (focal 10) at z = 4, 5, 6 looking down
  -z at points on the plane z = 0, and their observations: each point in each image."""
  poses = np.tile(np.eye(4, dtype=np.float32), (3, 1, 1))
  poses[:, 2, 3] = [4.0, 5.0, 6.0]
  points = np.array([[0.0, 0.0, 0.0], [0.5, -0.3, 0.0], [-0.6, 0.2, 0.0], [9.0, 0.0, 0.0],
                     [0.0, 0.0, 7.0]], np.float32)  # outside every image; behind every camera
  obs = np.array([[i, p] for i in range(3) for p in range(5)], np.int32)
  return Dataset(np.zeros((3, 8, 10, 3), np.float32), poses, (10.0, 10.0, 5.0, 4.0), near=1.0,
                 far=10.0, points=points, point_errors=np.array([1.0, 2.0, 3.0, 0.5, -1.0],
                                                                 np.float32),
                 observations=obs, masks=masks, image_cameras=image_cameras)


def test_keypoints_project_through_a_known_camera_and_drop_what_no_ray_reaches():
  dataset = _toy()
  data, kp = _keypoints(dataset)
  # Point 3 leaves every image, point 4 is behind every camera: dropped.
  kept = [(i, p) for i in range(3) for p in range(3)]
  np.testing.assert_array_equal(kp.image, [i for i, _ in kept])
  z = np.array([4.0, 5.0, 6.0])[[i for i, _ in kept]]
  xyz = dataset.points[[p for _, p in kept]]
  # Pinhole: u = f x / z + cx, v = -f y / z + cy (y up), less the pixel centre 0.5.
  np.testing.assert_allclose(kp.at, np.stack([10 * xyz[:, 0] / z + 5.0 - 0.5,
                                              -10 * xyz[:, 1] / z + 4.0 - 0.5], -1), atol=1e-5)
  np.testing.assert_allclose(kp.t, z, atol=1e-6)
  np.testing.assert_allclose(kp.scale, z, atol=1e-6)
  # Errors over the mean of the kept points' (1, 2, 3: mean 2).
  np.testing.assert_allclose(kp.error, np.tile([0.5, 1.0, 1.5], 3), atol=1e-6)
  rays = train_batches.keypoint_rays(data, kp)
  hit = np.asarray(rays.origins) + np.asarray(kp.t)[:, None] * np.asarray(rays.directions)
  np.testing.assert_allclose(hit, xyz, atol=1e-5)
  # Per-image cameras: each keypoint through its own image's camera.
  cams = Cameras.stack([(8, 10, (10.0, 10.0, 5.0, 4.0)), (8, 10, (20.0, 20.0, 1.0, 4.0)),
                        (8, 10, (10.0, 12.0, 5.0, 3.0))])
  own = _toy(image_cameras=cams)
  data, kp = _keypoints(own)
  assert data.cameras is not None and len(kp) == 8  # point 2 leaves image 1 at focal 20
  rays = train_batches.keypoint_rays(data, kp)
  hit = np.asarray(rays.origins) + np.asarray(kp.t)[:, None] * np.asarray(rays.directions)
  np.testing.assert_allclose(hit, own.points[np.asarray(own.observations)[[
      0, 1, 2, 5, 6, 10, 11, 12], 1]], atol=1e-5)


def test_a_masked_observation_drops_its_point():
  masks = np.ones((3, 8, 10), np.float32)
  masks[1, 4, 5] = 0.0  # the pixel point 0 falls in, in image 1 (u = 5, v = 4)
  data, kp = _keypoints(_toy(masks=masks))
  assert len(kp) == 6  # points 1 and 2 in each image; point 0 nowhere
  at = np.asarray(kp.at)
  assert not np.any(np.all(np.isclose(at, [4.5, 3.5]), -1))  # point 0's keypoint, everywhere
  np.testing.assert_allclose(kp.error, np.tile([0.8, 1.2], 3), atol=1e-6)  # mean of 2 and 3
  rays = train_batches.keypoint_rays(data, kp)
  hit = np.asarray(rays.origins) + np.asarray(kp.t)[:, None] * np.asarray(rays.directions)
  np.testing.assert_allclose(hit, np.tile(data_points := _toy().points[1:3], (3, 1)), atol=1e-5)
  del data_points


def test_subset_keeps_and_renumbers_each_images_observations():
  dataset = _toy()
  for indices in ([2, 0], slice(1, 3), np.array([1]), [0, 0]):
    part = dataset.subset(indices)
    chosen = np.arange(3)[indices]
    want = sorted((new, p) for new, old in enumerate(chosen) for i, p in
                  dataset.observations.tolist() if i == old)
    assert sorted(map(tuple, part.observations.tolist())) == want
    assert part.observations.dtype == np.int32
    np.testing.assert_array_equal(part.points, dataset.points)  # scene-wide
    np.testing.assert_array_equal(part.point_errors, dataset.point_errors)
  assert dataset.subset([]).observations.shape == (0, 2)
  assert Dataset(np.zeros((1, 2, 2, 3)), np.eye(4)[None], (1, 1, 1, 1)).subset(
      [0]).observations is None


def test_observations_of_missing_images_or_points_are_a_data_error():
  for obs in (np.array([[3, 0]]), np.array([[0, 5]]), np.array([[-1, 0]])):
    assert_data_error(["observations name an image or a point"], Dataset,
                      np.zeros((3, 8, 10, 3)), np.tile(np.eye(4), (3, 1, 1)),
                      (10.0, 10.0, 5.0, 4.0), points=np.zeros((5, 3)),
                      point_errors=np.zeros(5), observations=obs, name="toy")
  assert_data_error(["point_errors"], Dataset, np.zeros((3, 8, 10, 3)),
                    np.tile(np.eye(4), (3, 1, 1)), (10.0, 10.0, 5.0, 4.0),
                    points=np.zeros((5, 3)), observations=np.array([[0, 0]]))


def test_no_keypoints_are_built_unless_asked():
  data = train_batches.make_train_data(
      _toy(), (8, 10, (10.0, 10.0, 5.0, 4.0), 1.0, 10.0, 0.5, False), np.zeros(3, np.float32))
  assert data.keypoints is None
  assert jnp.asarray(data.rgb).shape == (3, 80, 3)


def test_an_llff_folder_with_a_broken_model_still_loads_without_tracks(tmp_path, capsys):
  truth, points, errors, model = tracked_scene()
  folder = str(tmp_path / "llff")
  llff.export_llff(truth, folder)
  sparse = os.path.join(folder, "sparse", "0")
  _write(model, sparse, binary=True)
  os.remove(os.path.join(sparse, "images.bin"))  # as an archive that lost its largest file
  dataset = llff.load_llff(folder)
  assert dataset.observations is None and dataset.point_errors is None
  np.testing.assert_allclose(dataset.poses, llff.load_llff(folder).poses)
  line = capsys.readouterr().out
  assert "images" in line and "its tracks are not used" in line
