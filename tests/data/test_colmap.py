"""COLMAP models loaded as they come (nerf_jax.data.colmap): a built-in scene exported with its
images, its cameras written as COLMAP's cameras/images/points3D by a writer of this file (binary
and text, from COLMAP's documented formats), then loaded and compared with the scene's truth."""

import os
import struct

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.data import colmap, scenes
from nerf_jax.data.llff import export_llff
from tests.helpers import assert_data_error, load_data, similarity

# COLMAP's model ids (src/colmap/sensor/models.h), for the writer.
MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4,
             "OPENCV_FISHEYE": 5}
GL_TO_CV = np.diag([1.0, -1.0, -1.0])  # camera axes: OpenGL (y up, z back) <-> OpenCV


def _quaternion(rot):
  """(w, x, y, z) of a rotation matrix (Shepperd's method, the largest pivot)."""
  trace = np.trace(rot)
  pivots = [trace, rot[0, 0], rot[1, 1], rot[2, 2]]
  k = int(np.argmax(pivots))
  if k == 0:
    w = 0.5 * np.sqrt(1 + trace)
    q = [w, (rot[2, 1] - rot[1, 2]) / (4 * w), (rot[0, 2] - rot[2, 0]) / (4 * w),
         (rot[1, 0] - rot[0, 1]) / (4 * w)]
  else:
    i, j, l = k - 1, k % 3, (k + 1) % 3
    s = 2 * np.sqrt(1 + rot[i, i] - rot[j, j] - rot[l, l])
    q = [0.0] * 4
    q[0] = (rot[l, j] - rot[j, l]) / s
    q[1 + i], q[1 + j] = 0.25 * s, (rot[j, i] + rot[i, j]) / s
    q[1 + l] = (rot[l, i] + rot[i, l]) / s
  return np.array(q) * (1 if q[0] >= 0 else -1)


def _world_to_camera(c2w):
  """(R, t) of COLMAP's world-to-camera (OpenCV axes) for a float [4, 4] OpenGL camera-to-world."""
  rot = c2w[:3, :3] @ GL_TO_CV
  return rot.T, -rot.T @ c2w[:3, 3]


def write_model(folder, cameras, images, points, binary):
  """COLMAP's three files in `folder`. cameras: list of (id, model, width, height, params);
  images: list of (id, c2w float [4, 4] OpenGL, camera id, name); points: float [P, 3]."""
  os.makedirs(folder, exist_ok=True)
  colours = (np.arange(3 * len(points)).reshape(-1, 3) * 7) % 256
  if binary:
    data = struct.pack("<Q", len(cameras))
    for cam_id, model, width, height, params in cameras:
      data += struct.pack("<iiQQ", cam_id, MODEL_IDS[model], width, height)
      data += struct.pack(f"<{len(params)}d", *params)
    with open(os.path.join(folder, "cameras.bin"), "wb") as f:
      f.write(data)
    data = struct.pack("<Q", len(images))
    for image_id, c2w, cam_id, name in images:
      rot, trans = _world_to_camera(c2w)
      data += struct.pack("<i4d3di", image_id, *_quaternion(rot), *trans, cam_id)
      data += name.encode() + b"\0" + struct.pack("<Q", 2)
      data += struct.pack("<ddq", 1.5, 2.5, -1) * 2  # 2D points seeing no 3D point
    with open(os.path.join(folder, "images.bin"), "wb") as f:
      f.write(data)
    data = struct.pack("<Q", len(points))
    for k, (p, c) in enumerate(zip(points, colours)):
      data += struct.pack("<Q3d3Bd", k + 1, *p, *c, 0.5) + struct.pack("<Q", 0)  # no track
    with open(os.path.join(folder, "points3D.bin"), "wb") as f:
      f.write(data)
    return
  lines = ["# Camera list with one line of data per camera:",
           "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
  lines += [" ".join([str(i), m, str(w), str(h)] + [repr(float(p)) for p in params])
            for i, m, w, h, params in cameras]
  with open(os.path.join(folder, "cameras.txt"), "w") as f:
    f.write("\n".join(lines) + "\n")
  lines = ["# Image list with two lines of data per image:",
           "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
           "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
  for k, (image_id, c2w, cam_id, name) in enumerate(images):
    rot, trans = _world_to_camera(c2w)
    lines.append(" ".join([str(image_id)] + [repr(float(v)) for v in _quaternion(rot)] +
                          [repr(float(v)) for v in trans] + [str(cam_id), name]))
    lines.append("" if k % 2 else "1.5 2.5 -1 3.0 4.0 -1")  # no 2D points: a blank line
  with open(os.path.join(folder, "images.txt"), "w") as f:
    f.write("\n".join(lines) + "\n")
  lines = ["# 3D point list with one line of data per point:",
           "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
  lines += [" ".join([str(k + 1)] + [repr(float(v)) for v in p] + [str(int(v)) for v in c] +
                     ["0.5"]) for k, (p, c) in enumerate(zip(points, colours))]  # no tracks
  with open(os.path.join(folder, "points3D.txt"), "w") as f:
    f.write("\n".join(lines) + "\n")


HEIGHT, WIDTH, VIEWS = 20, 28, 10


def _scene_folder(tmp_path, binary, keep_llff=False):
  """(folder, truth Dataset, points float [P, 3]): the 'diffuse' scene's views as images/ (by
  export_llff) and its cameras as a COLMAP model in sparse/0 (one PINHOLE camera)."""
  truth = scenes.make_dataset("diffuse", num_views=VIEWS, height=HEIGHT, width=WIDTH)
  folder = str(tmp_path / "scene")
  export_llff(truth, folder)  # images/000.png ...
  if not keep_llff:
    os.remove(os.path.join(folder, "poses_bounds.npy"))
  fx, fy, cx, cy = truth.intrinsics
  # Our rays pass through (i + pixel_center - cx) / f; COLMAP's through (i + 0.5 - cx') / f.
  shift = 0.5 - truth.pixel_center
  cameras = [(3, "PINHOLE", WIDTH, HEIGHT, [fx, fy, cx + shift, cy + shift])]
  names = sorted(os.listdir(os.path.join(folder, "images")))
  # Image ids in an order unlike the names': the loader must sort by name.
  images = [(100 - k, truth.poses[k].astype(np.float64), 3, names[k]) for k in range(VIEWS)]
  points = np.random.default_rng(0).uniform(-1.0, 1.0, (300, 3)) * [1.0, 0.6, 0.8]
  write_model(os.path.join(folder, "sparse", "0"), cameras, images[::-1], points, binary)
  return folder, truth, points


@pytest.mark.parametrize("binary", [True, False], ids=["bin", "txt"])
def test_model_loads_with_the_scenes_poses_intrinsics_images_and_points(tmp_path, binary):
  folder, truth, points = _scene_folder(tmp_path, binary)
  train, test = load_data({"path": folder})
  order = [0, 8] + [k for k in range(VIEWS) if k % 8]  # test: every 8th view, from 0
  assert (len(train), len(test)) == (8, 2)
  images = np.concatenate([test.images, train.images])
  poses = np.concatenate([test.poses, train.poses]).astype(np.float64)
  np.testing.assert_allclose(images, truth.images[order], rtol=0, atol=0.5 / 255 + 1e-6)
  # The rays: focal lengths and where each pixel's ray passes, not the stored numbers alone.
  fx, fy, cx, cy = test.intrinsics
  tfx, tfy, tcx, tcy = truth.intrinsics
  np.testing.assert_allclose([fx, fy, test.pixel_center - cx, test.pixel_center - cy],
                             [tfx, tfy, truth.pixel_center - tcx, truth.pixel_center - tcy],
                             rtol=1e-6, atol=1e-6)
  assert train.image_cameras is None and test.intrinsics == train.intrinsics
  # The loader moves the world (z up, points in [-1, 1]^3): a similarity that takes the true
  # camera centres to the loaded ones must also take each camera's axes and every point there.
  true_poses = truth.poses[order].astype(np.float64)
  scale, rot, offset = similarity(true_poses[:, :3, 3], poses[:, :3, 3])
  np.testing.assert_allclose(poses[:, :3, 3], scale * true_poses[:, :3, 3] @ rot.T + offset,
                             atol=1e-4 * scale)
  np.testing.assert_allclose(poses[:, :3, :3], rot @ true_poses[:, :3, :3], atol=1e-5)
  np.testing.assert_allclose(test.points, scale * points @ rot.T + offset, atol=1e-4 * scale)
  np.testing.assert_array_equal(train.points, test.points)
  # near, far: 0.8x the 1st and 1.2x the 99th percentile of the points' depths in front of the
  # cameras (as for transforms.json), in the loaded units.
  rel = points[None] - true_poses[:, None, :3, 3]
  depth = -np.einsum("npi,ni->np", rel, true_poses[:, :3, 2]).ravel()
  depth = depth[depth > 0] * scale
  np.testing.assert_allclose([test.near, test.far], [0.8 * np.percentile(depth, 1),
                                                     1.2 * np.percentile(depth, 99)], rtol=1e-4)
  assert test.core is not None and np.array_equal(test.core, test.aabb)
  inside = np.all((test.points >= test.core[0]) & (test.points <= test.core[1]), axis=1)
  assert inside.mean() > 0.97
  assert not test.forward_facing and test.accs is None


def test_factor_reads_images_n_or_block_averages(tmp_path):
  folder, truth, _ = _scene_folder(tmp_path, binary=True)
  train, test = load_data({"path": folder, "factor": 2})
  full = np.stack([iio.imread(os.path.join(folder, "images", n)) / 255.0
                   for n in sorted(os.listdir(os.path.join(folder, "images")))])
  halved = full.reshape(VIEWS, HEIGHT // 2, 2, WIDTH // 2, 2, 3).mean((2, 4))
  np.testing.assert_allclose(test.images, halved[[0, 8]], atol=1e-6)
  fx, _, cx, cy = test.intrinsics
  np.testing.assert_allclose([fx, test.pixel_center - cx, test.pixel_center - cy],
                             [truth.intrinsics[0] / 2, 0.5 - truth.intrinsics[2] / 2,
                              0.5 - truth.intrinsics[3] / 2], atol=1e-6)
  os.makedirs(os.path.join(folder, "images_2"))
  for k, name in enumerate(sorted(os.listdir(os.path.join(folder, "images")))):
    iio.imwrite(os.path.join(folder, "images_2", name),
                np.full((HEIGHT // 2, WIDTH // 2, 3), 10 * k, np.uint8))
  _, test = load_data({"path": folder, "factor": 2})
  np.testing.assert_allclose(test.images[1], np.full((HEIGHT // 2, WIDTH // 2, 3), 80 / 255),
                             atol=1e-6)


def _distort(x, y, model, params):
  """COLMAP's distortion of normalised coordinates (src/colmap/sensor/models.h, written out)."""
  r2 = x * x + y * y
  if model in ("SIMPLE_PINHOLE", "PINHOLE"):
    return x, y
  if model == "SIMPLE_RADIAL":
    radial = 1 + params[3] * r2
    return x * radial, y * radial
  if model == "RADIAL":
    radial = 1 + params[3] * r2 + params[4] * r2 * r2
    return x * radial, y * radial
  k1, k2, p1, p2 = params[4:8]
  radial = 1 + k1 * r2 + k2 * r2 * r2
  return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
          y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y))


def _focal(model, params):
  """(fx, fy, cx, cy) of COLMAP camera params."""
  if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
    return params[0], params[0], params[1], params[2]
  return tuple(params[:4])


def _photo(height, width, phase):
  """float64 [H, W, 3]: a smooth pattern of COLMAP pixel coordinates (centres at +0.5)."""
  v, u = np.mgrid[0:height, 0:width] + 0.5
  return _pattern(u, v, phase)


def _pattern(u, v, phase):
  return np.stack([0.5 + 0.4 * np.sin(u / 5.0 + phase), 0.5 + 0.4 * np.cos(v / 4.0 - phase),
                   0.5 + 0.3 * np.sin((u + v) / 7.0)], -1)


def _look_at(centre):
  """float [4, 4] OpenGL camera-to-world at `centre` looking at the origin, z up."""
  back = centre / np.linalg.norm(centre)
  right = np.cross([0.0, 0.0, 1.0], back)
  right /= np.linalg.norm(right)
  pose = np.eye(4)
  pose[:3, :3] = np.stack([right, np.cross(back, right), back], 1)
  pose[:3, 3] = centre
  return pose


@pytest.mark.parametrize("model,params", [
    ("SIMPLE_PINHOLE", [33.0, 19.6, 15.3]),
    ("PINHOLE", [33.0, 35.0, 19.6, 15.3]),
    ("SIMPLE_RADIAL", [33.0, 19.6, 15.3, -0.2]),
    ("RADIAL", [33.0, 19.6, 15.3, -0.15, 0.05]),
    ("OPENCV", [33.0, 35.0, 19.6, 15.3, -0.1, 0.02, 0.03, -0.02])])
def test_distortion_is_removed_and_each_camera_kept(tmp_path, model, params):
  """Images 0, 1 through `model` (40 x 30), images 2, 3 through a PINHOLE of another size: each
  loaded pixel shows the photo where COLMAP's model (written out here) projects its ray."""
  folder = str(tmp_path)
  sizes = {1: (30, 40), 2: (24, 36)}
  cameras = [(1, model, 40, 30, params), (2, "PINHOLE", 36, 24, [30.0, 30.0, 18.0, 12.0])]
  os.makedirs(os.path.join(folder, "images"))
  images = []
  for k in range(4):
    cam = 1 if k < 2 else 2
    name = f"img_{k}.png"
    iio.imwrite(os.path.join(folder, "images", name),
                np.round(_photo(*sizes[cam], k) * 255).astype(np.uint8))
    angle = 0.7 * k
    images.append((k + 1, _look_at(np.array([4 * np.cos(angle), 4 * np.sin(angle), 1.0])),
                   cam, name))
  points = np.random.default_rng(1).uniform(-1, 1, (50, 3))
  write_model(os.path.join(folder, "sparse", "0"), cameras, images, points, binary=True)
  dataset, names = colmap.load(folder)
  assert names == [f"img_{k}.png" for k in range(4)]
  assert dataset.image_cameras is not None and dataset.mixed_sizes
  for k in range(4):
    cam_model, cam_params = (model, params) if k < 2 else ("PINHOLE", cameras[1][4])
    height, width, (fx, fy, cx, cy) = dataset.cameras.camera(k)
    assert (height, width) == sizes[1 if k < 2 else 2]
    tfx, tfy, tcx, tcy = _focal(cam_model, cam_params)
    # The pinhole keeps the camera's focal lengths and principal point (pixel_center 0).
    np.testing.assert_allclose([fx, fy, dataset.pixel_center - cx, dataset.pixel_center - cy],
                               [tfx, tfy, 0.5 - tcx, 0.5 - tcy], atol=1e-9)
    v, u = np.mgrid[0:height, 0:width] + 0.5
    xd, yd = _distort((u - tcx) / tfx, (v - tcy) / tfy, cam_model, cam_params)
    su, sv = tfx * xd + tcx, tfy * yd + tcy  # where the ray meets the photo
    inside = (su > 1.5) & (su < width - 1.5) & (sv > 1.5) & (sv < height - 1.5)
    assert inside.mean() > 0.6
    expected = _pattern(su, sv, k)
    # 8-bit photos read back by bilinear interpolation: ~0.004 off at most.
    np.testing.assert_allclose(dataset.image(k)[inside], expected[inside], atol=0.008)


def _break(folder, name, transform):
  path = os.path.join(folder, "sparse", "0", name)
  mode = "b" if name.endswith(".bin") else ""
  with open(path, "r" + mode) as f:
    content = f.read()
  with open(path, "w" + mode) as f:
    f.write(transform(content))
  return path


def test_malformed_files_name_the_file(tmp_path):
  folder, _, _ = _scene_folder(tmp_path / "a", binary=True)
  _break(folder, "cameras.bin", lambda b: b[:-5])
  assert_data_error(["cameras.bin", "truncated"], load_data, {"path": folder})
  folder, _, _ = _scene_folder(tmp_path / "b", binary=True)
  _break(folder, "points3D.bin", lambda b: b + b"\0\0\0")
  assert_data_error(["points3D.bin", "3 bytes after"], load_data, {"path": folder})
  folder, _, _ = _scene_folder(tmp_path / "c", binary=False)
  _break(folder, "images.txt", lambda t: t.replace(" 3 0", " x 0", 1))
  assert_data_error(["images.txt", "line 4"], load_data, {"path": folder})
  folder, _, _ = _scene_folder(tmp_path / "d", binary=False)
  _break(folder, "cameras.txt", lambda t: t.replace("PINHOLE 28 20", "PINHOLE 28 20 1.0"))
  assert_data_error(["cameras.txt", "line 3", "PINHOLE takes 4 parameters"], load_data,
                    {"path": folder})
  folder, _, _ = _scene_folder(tmp_path / "e", binary=True)
  os.remove(os.path.join(folder, "images", "003.png"))
  assert_data_error(["003.png", "not found"], load_data, {"path": folder})
  folder, _, _ = _scene_folder(tmp_path / "f", binary=True)
  os.remove(os.path.join(folder, "sparse", "0", "points3D.bin"))
  assert_data_error(["sparse/0", "points3D"], load_data, {"path": folder})


@pytest.mark.parametrize("binary", [True, False], ids=["bin", "txt"])
def test_unsupported_camera_model_is_named(tmp_path, binary):
  folder = str(tmp_path)
  os.makedirs(os.path.join(folder, "images"))
  iio.imwrite(os.path.join(folder, "images", "a.png"), np.zeros((8, 8, 3), np.uint8))
  write_model(os.path.join(folder, "sparse", "0"),
              [(1, "OPENCV_FISHEYE", 8, 8, [8.0, 8.0, 4.0, 4.0, 0.1, 0.0, 0.0, 0.0])],
              [(1, _look_at(np.array([0.0, -4.0, 0.0])), 1, "a.png")],
              np.zeros((0, 3)), binary)
  assert_data_error(["cameras.", "OPENCV_FISHEYE", "not supported"], colmap.load, folder)


def test_llff_folder_with_a_model_stays_llff(tmp_path):
  """LLFF's own data has poses_bounds.npy and sparse/0: poses_bounds.npy decides."""
  folder, _, _ = _scene_folder(tmp_path, binary=True, keep_llff=True)
  assert load_data({"path": folder})[0].forward_facing
  os.remove(os.path.join(folder, "poses_bounds.npy"))
  assert load_data({"path": folder})[0].points is not None


@pytest.mark.parametrize("write", ["write_binary", "write_text"])
def test_files_that_colmap_itself_writes_load_alike(tmp_path, write):
  """COLMAP (pycolmap, the optional `capture` extra) reads the model written here and writes it
  out again, binary or text: the loader reads its files as it reads ours."""
  pycolmap = pytest.importorskip("pycolmap")
  folder, truth, _ = _scene_folder(tmp_path, binary=True)
  model = pycolmap.Reconstruction(os.path.join(folder, "sparse", "0"))
  for image in model.images.values():  # COLMAP reads this file's poses as written
    rot, trans = _world_to_camera(truth.poses[int(image.name[:3])].astype(np.float64))
    np.testing.assert_allclose(image.cam_from_world().matrix(),
                               np.concatenate([rot, trans[:, None]], 1), atol=1e-6)
  mine = load_data({"path": folder})[0]
  getattr(model, write)(os.path.join(folder, "sparse", "0"))  # over ours (.bin) or beside it
  if write == "write_text":
    for name in colmap.FILES:
      os.remove(os.path.join(folder, "sparse", "0", name + ".bin"))
  theirs = load_data({"path": folder})[0]
  np.testing.assert_allclose(theirs.poses, mine.poses, atol=1e-6)
  np.testing.assert_array_equal(theirs.images, mine.images)
  np.testing.assert_allclose(theirs.points, mine.points, atol=1e-6)
  assert theirs.intrinsics == pytest.approx(mine.intrinsics, abs=1e-9)


def test_masks_beside_the_images_are_read_and_scaled(tmp_path):
  """masks/<image name>: white keeps; with data.factor a block is kept only if all of it is."""
  folder, _, _ = _scene_folder(tmp_path, binary=True)
  names = sorted(os.listdir(os.path.join(folder, "images")))
  truth = np.ones((VIEWS, HEIGHT, WIDTH), np.float32)
  os.makedirs(os.path.join(folder, "masks"))
  for k, name in enumerate(names):
    truth[k, k:k + 3, 2 * k + 1:2 * k + 4] = 0.0  # a 3 x 3 patch ignored, different per view
    iio.imwrite(os.path.join(folder, "masks", name), (truth[k] * 255).astype(np.uint8))
  train, test = load_data({"path": folder})
  np.testing.assert_array_equal(test.masks, truth[[0, 8]])
  np.testing.assert_array_equal(train.masks, truth[[k for k in range(VIEWS) if k % 8]])
  _, test = load_data({"path": folder, "factor": 2})
  pooled = truth.reshape(VIEWS, HEIGHT // 2, 2, WIDTH // 2, 2).min((2, 4))
  np.testing.assert_array_equal(test.masks, pooled[[0, 8]])
  os.remove(os.path.join(folder, "masks", names[3]))
  assert_data_error(["masks", names[3]], load_data, {"path": folder})
