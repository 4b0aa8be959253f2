"""The 'detail' scene: exact depth and coverage, textures, gloss, Blender export, cache."""

import dataclasses
import os

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.run import config_lib
from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data import scenes
from nerf_jax.data import export, loaders
from nerf_jax.data.scenes import cache, detail, raycast, tracer
from tests.helpers import load_data, small_config
from tests import helpers

SCENE = detail.SCENE
S = SCENE.supersample
PLINTH_SIZE = detail.PLINTH.size[0]


def _look(eye, target, up=(0.0, 0.0, 1.0)):
  """float64 [4, 4] camera-to-world at `eye` looking at `target` (camera -z forward, +y up)."""
  eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
  back = (eye - target) / np.linalg.norm(eye - target)
  right = np.cross(up, back)
  right /= np.linalg.norm(right)
  pose = np.eye(4)
  pose[:3, :3] = np.stack([right, np.cross(back, right), back], -1)
  pose[:3, 3] = eye
  return pose


def _subsample_rays(pose, size, focal):
  """The s x s rays of every pixel, as `tracer` places them: origins, directions float64
  [size, size, s * s, 3] (pixel_center 0)."""
  offsets = (np.arange(S) + 0.5) / S - 0.5
  ox, oy = [a.ravel() for a in np.meshgrid(offsets, offsets, indexing="xy")]
  j, i = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
  x = (i[..., None] + ox - 0.5 * size) / focal
  y = -(j[..., None] + oy - 0.5 * size) / focal
  cam = np.stack([x, y, -np.ones_like(x)], -1)
  directions = cam @ pose[:3, :3].T
  return np.broadcast_to(pose[:3, 3], directions.shape), directions


def _rod_t(o, d, start, end, radius):
  """Closed-form entry t of rays (float64 [..., 3]) into a capped cylinder, inf on a miss: the
  side's interval from the textbook quadratic (fine in float64) meets the caps' slab."""
  a, b = np.asarray(start, np.float64), np.asarray(end, np.float64)
  length = np.linalg.norm(b - a)
  u = (b - a) / length
  oc = o - a
  dp = d - (d @ u)[..., None] * u
  op = oc - (oc @ u)[..., None] * u
  qa, qb, qc = (dp * dp).sum(-1), (op * dp).sum(-1), (op * op).sum(-1) - radius ** 2
  root = np.sqrt(np.maximum(qb * qb - qa * qc, 0.0))
  side_in, side_out = (-qb - root) / qa, (-qb + root) / qa
  with np.errstate(divide="ignore"):  # rays across the axis: the slab is (-inf, inf)
    c0, c1 = (0.0 - oc @ u) / (d @ u), (length - oc @ u) / (d @ u)
  t_in = np.maximum(side_in, np.minimum(c0, c1))
  t_out = np.minimum(side_out, np.maximum(c0, c1))
  return np.where((qb * qb - qa * qc >= 0) & (t_in <= t_out), t_in, np.inf)


def test_ring_rods_float32_intersections_match_float64_closed_form():
  rng = np.random.default_rng(0)
  rods = [o.shape for o in SCENE.objects if isinstance(o.shape, raycast.Rod)]
  assert max(r.radius for r in rods) <= 0.01  # well under a 0.023-wide grid cell
  for rod in rods[2:6]:  # ring rods, tilted
    a, b = np.asarray(rod.start), np.asarray(rod.end)
    targets = a + rng.uniform(0.05, 0.95, (200, 1)) * (b - a) + rng.normal(0, 0.006, (200, 3))
    eyes = rng.normal(size=(200, 3))
    eyes = 4.0 * eyes / np.linalg.norm(eyes, axis=-1, keepdims=True)
    d = (targets - eyes) / 2.0
    t_ref = _rod_t(eyes, d, a, b, rod.radius)
    t_in, _, normal = (np.asarray(x, np.float64) for x in raycast.intersect(
        rod, eyes.astype(np.float32), d.astype(np.float32)))
    hit = np.isfinite(t_ref)
    assert 40 < hit.sum() < 190
    np.testing.assert_allclose(t_in[hit], t_ref[hit], atol=2e-6)  # z-depth ~2, float32
    assert np.mean(np.isfinite(t_in) != hit) <= 0.01  # only rays grazing an edge may differ
    points = eyes[hit] + t_ref[hit, None] * d[hit] - a
    axis = (b - a) / np.linalg.norm(b - a)
    along = points @ axis
    side = (along > 1e-4) & (along < np.linalg.norm(b - a) - 1e-4)  # entered through the side
    assert side.sum() > 30
    expected = (points - along[:, None] * axis) / rod.radius  # closed-form unit normal
    # float32 leaves ~1e-6 of a ray 4 units long in q, ~2e-4 of the 0.006 radius, in the normal.
    np.testing.assert_allclose(normal[hit][side], expected[side], atol=1e-3)


def test_antenna_depth_and_coverage_are_exact():
  a, b = np.asarray(detail.ANTENNA.start), np.asarray(detail.ANTENNA.end)
  target = np.array([a[0], a[1], 0.75])  # above everything but the antenna
  pose = _look(target + [0.3, -3.99, 0.0], target)
  size, focal = 24, 700.0  # the rod is 2 * 0.006 * 700 / 4 ~ 2.1 px wide
  out = tracer.render_images(SCENE, pose[None], size, size, focal)
  o, d = _subsample_rays(pose, size, focal)
  t = _rod_t(o, d, a, b, detail.ROD_RADIUS)
  coverage = np.isfinite(t).mean(-1)
  np.testing.assert_array_equal(np.round(out["acc"][0] * S * S), np.isfinite(t).sum(-1))
  assert ((coverage > 0) & (coverage < 1)).sum() >= 2 * size  # fractional on both edges
  assert (coverage == 0).sum() > size * size // 2
  centre = t[..., S * S // 2]  # s odd: the centre ray is a subsample
  hit = np.isfinite(centre)
  assert hit.sum() >= size
  np.testing.assert_allclose(out["depth"][0][hit], centre[hit], atol=1e-5)
  np.testing.assert_array_equal(out["depth"][0][~hit], SCENE.far)
  np.testing.assert_array_equal(out["rgb"][0][coverage == 0], 0.0)  # black, empty background


def test_plinth_face_depth_alpha_and_edge_coverage():
  half = 0.5 * PLINTH_SIZE
  eye = np.array([half - 0.06, half - 0.2, -0.54 + 4.0])  # above the free corner of the plinth
  pose = np.eye(4)
  pose[:3, 3] = eye  # looking straight down
  size, focal = 24, 400.0  # footprint 0.24 x 0.24 on the plinth: its edge x = 0.75 in view
  out = tracer.render_images(SCENE, pose[None], size, size, focal)
  o, d = _subsample_rays(pose, size, focal)
  t = 4.0 / -d[..., 2]  # closed form: the plane z = -0.54, 4 below the camera
  xy = o[..., :2] + t[..., None] * d[..., :2]
  inside = np.all(np.abs(xy) <= half, -1)
  coverage = inside.mean(-1)
  np.testing.assert_array_equal(np.round(out["acc"][0] * S * S), inside.sum(-1))
  assert (coverage == 1).sum() > 200 and (coverage == 0).sum() > 20
  assert ((coverage > 0) & (coverage < 1)).sum() >= size  # the edge crosses pixels
  full = coverage == 1
  np.testing.assert_allclose(out["depth"][0][full], 4.0, atol=1e-5)
  assert np.all(out["depth"][0][coverage == 0] == SCENE.far)
  assert np.all(out["rgb"][0][full].max(-1) > 0.05)  # lit, textured paper


def _rays_to(point, view_dirs, dist=3.0):
  """helpers.rays_to in float32."""
  return tuple(a.astype(np.float32) for a in helpers.rays_to(point, view_dirs, dist))


def _trace(origins, directions, near, far, pad=512):
  """`tracer.trace_rays` of float [N, 3] rays (N <= pad), padded to one shape so that every test
  shares one compilation. Returns rgb float64 [N, 3], t float64 [N], hit bool [N]."""
  n = len(origins)
  fill = lambda a: np.concatenate([a, np.repeat(a[:1], pad - n, 0)]).astype(np.float32)
  out = tracer.trace_rays(SCENE, fill(origins), fill(directions), near, far)
  return tuple(np.asarray(a)[:n].astype(np.float64 if a.dtype != bool else bool) for a in out)


def _colours_from(points, dirs_a, dirs_b):
  """rgb float64 [N, 3] of each point seen along two directions, and whether both rays hit it."""
  out = []
  for dirs in (dirs_a, dirs_b):
    o, d = _rays_to(points, dirs)
    rgb, t, _ = _trace(o, d, 0.1, 10.0)
    out.append((rgb, np.abs(t - 1.5) < 1e-5))  # 3 / |d| = 1.5: the ray ends at the point
  (rgb_a, ok_a), (rgb_b, ok_b) = out
  return rgb_a, rgb_b, ok_a & ok_b


def test_diffuse_texture_is_view_consistent():
  rng = np.random.default_rng(1)
  n = 400
  top = np.stack([rng.uniform(-0.7, 0.7, n), rng.uniform(-0.7, 0.7, n), np.full(n, -0.54)], -1)
  front = np.stack([rng.uniform(-0.58, -0.12, n), np.full(n, -0.55), rng.uniform(-0.52, -0.06, n)],
                   -1)  # the crate's -y face
  for points, side in ((top, [0, 0, 1]), (front, [0, -1, 0])):
    dirs_a = rng.normal(size=(n, 3)) * 0.4 + side
    dirs_b = rng.normal(size=(n, 3)) * 0.4 + side
    rgb_a, rgb_b, both = _colours_from(points, dirs_a, dirs_b)
    assert both.sum() > n // 4  # the rest are occluded from one of the two directions
    # The two hit points agree to float32 rounding (~1e-7), which can flip a point lying within
    # that of a glyph's or stripe's edge: allow 1% of such points, none elsewhere.
    same = np.all(np.abs(rgb_a - rgb_b) <= 1e-5, -1)[both]
    assert same.mean() >= 0.99, same.mean()
    assert np.std(rgb_a[both].sum(-1)) > 0.05  # and the points differ from one another


def test_glossy_sphere_changes_with_viewing_direction():
  light = np.asarray(SCENE.light.direction) / np.linalg.norm(SCENE.light.direction)
  point = np.asarray(detail.GLOSSY.center) + detail.GLOSSY.radius * light  # normal = light
  rgb_a, rgb_b, both = _colours_from(point[None], light[None], np.array([[0.6, -0.7, 0.4]]))
  assert both.all()
  assert np.all(rgb_a - rgb_b > 0.15)  # the mirror direction sees the highlight


def _gradient_energy(image):
  """Mean squared difference of horizontally and vertically adjacent pixels."""
  return np.mean([(np.diff(image, axis=axis) ** 2).sum(-1).mean() for axis in (0, 1)])


def test_texture_has_high_frequency_content():
  flat = dataclasses.replace(SCENE, objects=tuple(
      dataclasses.replace(o, material=dataclasses.replace(o.material, texture=None))
      for o in SCENE.objects))
  pose = np.eye(4)
  pose[:3, 3] = (0.58, 0.58, 3.46)  # straight down on a free part of the plinth's top
  focal = 4 * scenes.TINY_NERF_FOCAL  # the scene's 400 px resolution
  out = tracer.render_images(SCENE, pose[None], 40, 40, focal)
  ref = scenes.render_view(flat, pose, 40, 40, focal)  # the same scene without texture
  np.testing.assert_array_equal(out["acc"], 1.0)  # all plinth
  np.testing.assert_array_equal(ref["acc"], 1.0)
  textured, plain = (_gradient_energy(a.astype(np.float64)) for a in (out["rgb"][0], ref["rgb"]))
  # A flat colour on a plane lit by a directional light is one colour: no gradient at all.
  assert plain < 1e-12, plain
  assert textured > 0.005, textured  # r.m.s. step > 0.07 between neighbouring pixels


def test_simulator_and_tracer_agree_on_one_ray_per_pixel():
  pose = rays_lib.pose_spherical(200.0, -30.0, 4.0)
  ref = scenes.render_view(SCENE, pose, 16, 16, 22.2)  # float64 numpy reference
  o, d = (np.asarray(a, np.float64).reshape(-1, 3) for a in rays_lib.get_rays(16, 16, 22.2, pose))
  rgb, t, hit = _trace(o, d, SCENE.near, SCENE.far)
  assert 0.1 < ref["acc"].mean() < 0.9
  # float32 and float64 may disagree on a ray grazing an edge (or a glyph's): at most 1%.
  agree = (np.all(np.abs(rgb - ref["rgb"].reshape(-1, 3)) <= 1e-4, -1)
           & (hit == (ref["acc"].ravel() == 1.0)))
  assert agree.mean() >= 0.99
  depth = np.where(hit, t, SCENE.far)
  np.testing.assert_allclose(depth[agree], ref["depth"].ravel()[agree], atol=1e-5)


def test_blender_export_round_trips_with_alpha(tmp_path):
  ds = scenes.make_dataset("detail", num_views=5, height=20, width=20)
  assert ds.images.shape == (5, 20, 20, 3) and ds.focal == pytest.approx(20 * 1.3888887889922)
  assert ((ds.accs > 0) & (ds.accs < 1)).any() and (ds.accs == 0).any() and (ds.accs == 1).any()
  export.export_blender(ds, str(tmp_path), background=ds.background)
  png = iio.imread(tmp_path / "train" / "r_0.png")
  assert png.shape == (20, 20, 4) and ((png[..., 3] > 0) & (png[..., 3] < 255)).any()
  train = loaders.load_blender(str(tmp_path), background=(0.0, 0.0, 0.0))
  np.testing.assert_allclose(train.accs, ds.accs[:4], atol=0.5 / 255 + 1e-6)
  np.testing.assert_allclose(train.images, ds.images[:4], atol=1.5 / 255)
  np.testing.assert_allclose(train.poses, ds.poses[:4])
  white = loaders.load_blender(str(tmp_path), background=(1.0, 1.0, 1.0), split="test")
  expected = ds.images[4:] + (1.0 - ds.accs[4:, ..., None])  # re-composited on white
  np.testing.assert_allclose(white.images, expected, atol=1.5 / 255)
  assert export.main(["--scene=detail", "--format=blender", "--alpha", "--num_views=2",
                      "--image_size=8", f"--out={tmp_path / 'cli'}"]) == 0
  assert iio.imread(tmp_path / "cli" / "train" / "r_0.png").shape == (8, 8, 4)


def test_large_renders_are_cached(tmp_path, monkeypatch):
  monkeypatch.setenv("NERF_JAX_CACHE", str(tmp_path))
  monkeypatch.setattr(cache, "MIN_RAYS", 1)
  first = scenes.make_dataset("detail", num_views=2, height=8, width=8)
  assert len(os.listdir(tmp_path)) == 1
  monkeypatch.setattr(tracer, "render_images", lambda *a, **k: pytest.fail("not cached"))
  again = scenes.make_dataset("detail", num_views=2, height=8, width=8)
  np.testing.assert_array_equal(again.images, first.images)
  np.testing.assert_array_equal(again.depths, first.depths)
  pose = scenes.random_poses(2)
  assert cache.key(SCENE, pose, height=8) != cache.key(SCENE, pose, height=9)
  other = dataclasses.replace(SCENE, objects=SCENE.objects[:-1])
  assert cache.key(SCENE, pose, height=8) != cache.key(other, pose, height=8)


def test_default_size_and_config():
  config = config_lib.load("scenes/detail")
  assert config.data.image_size == SCENE.image_size == 400 and config.model.view_dependent
  assert SCENE.effects.names() == {"view_dependent"} and SCENE.background == (0.0, 0.0, 0.0)


def test_detail_config_loads_the_scene():
  config = small_config({"data.num_views": 5, "data.image_size": 12}, base="scenes/detail")
  train, test = load_data(config.data)
  assert (len(train), len(test)) == (4, 1) and train.images.shape[1:] == (12, 12, 3)
  assert train.name == "detail" and 0 < train.accs.mean() < 1
