"""Tests of the built-in scenes and their ground-truth simulator."""

import dataclasses

import numpy as np
import pytest

from nerf_jax.cameras import rays as rays_lib
from nerf_jax.data import scenes
from nerf_jax.data.scenes import garden, simulator
from nerf_jax.data.scenes import scene as scene_lib
from nerf_jax.data.scenes.geometry import Box, Cylinder, Sphere
from tests import helpers

LOOK_DOWN = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4.0], [0, 0, 0, 1]])  # at z = 4


def _one_sphere(**kw):
  obj = scenes.Object(Sphere((0.0, 0.0, 0.0), 0.5), scenes.Material((0.5, 0.5, 0.5)))
  return scenes.Scene("one", (obj,), scenes.Effects(**kw),
                      background=(1.0, 1.0, 1.0) if kw.get("background") else (0.0, 0.0, 0.0))


def test_head_on_sphere_has_analytic_depth():
  out = scenes.render_view(_one_sphere(), LOOK_DOWN, 3, 3, focal=10.0, pixel_center=0.5)
  assert out["depth"][1, 1] == pytest.approx(4.0 - 0.5, abs=1e-6)
  assert out["acc"][1, 1] == 1.0


def test_depth_is_z_depth_of_the_hit_point():
  out = scenes.render_view(_one_sphere(), LOOK_DOWN, 9, 9, focal=20.0)
  o, d = (np.asarray(a, np.float64) for a in rays_lib.get_rays(9, 9, 20.0, LOOK_DOWN))
  hit = out["acc"] == 1.0
  assert 0 < hit.sum() < 81
  points = o[hit] + out["depth"][hit, None] * d[hit]
  np.testing.assert_allclose(np.linalg.norm(points, axis=-1), 0.5, atol=1e-5)
  np.testing.assert_allclose(out["depth"][hit], 4.0 - points[:, 2], atol=1e-5)  # camera at z=4


def test_empty_ray_is_background_with_far_depth():
  out = simulator.trace_rays(_one_sphere(background=True), [[0.0, 0.0, 4.0]], [[0.0, 0.0, 1.0]])
  assert out["acc"][0] == 0.0 and out["depth"][0] == 6.0
  np.testing.assert_array_equal(out["rgb"][0], 1.0)


def test_only_surfaces_between_near_and_far_count():
  o, d = [[0.0, 0.0, 4.0]], [[0.0, 0.0, -1.0]]  # the sphere spans t in [3.5, 4.5]
  assert simulator.trace_rays(_one_sphere(), o, d, near=2.0, far=3.0)["acc"][0] == 0.0
  inside = simulator.trace_rays(_one_sphere(), o, d, near=4.0, far=6.0)  # starts in the solid
  assert inside["acc"][0] == 1.0 and inside["depth"][0] == 4.0


@pytest.mark.parametrize("shape", [Sphere((0.1, -0.2, 0.3), 0.6),
                                   Box((0.1, -0.2, 0.3), (0.8, 0.5, 1.1)),
                                   Cylinder((0.1, -0.2, 0.3), 0.5, 0.9)])
def test_intersection_interval_matches_point_membership(shape):
  rng = np.random.default_rng(0)
  origins = rng.normal(size=(1000, 3)) * 3.0
  directions = rng.uniform(-1, 1, size=(1000, 3)) * 0.2 - origins * 0.3  # many towards the shape
  t_in, t_out, normal = shape.intersect(origins, directions)
  t = np.linspace(-10.0, 10.0, 2001)
  points = origins[:, None] + t[None, :, None] * directions[:, None]
  c = np.asarray(shape.center)
  if isinstance(shape, Sphere):
    inside = np.linalg.norm(points - c, axis=-1) <= shape.radius
  elif isinstance(shape, Box):
    inside = np.all(np.abs(points - c) <= 0.5 * np.asarray(shape.size), axis=-1)
  else:
    inside = ((np.linalg.norm((points - c)[..., :2], axis=-1) <= shape.radius)
              & (np.abs((points - c)[..., 2]) <= 0.5 * shape.height))
  expected = (t >= t_in[:, None]) & (t <= t_out[:, None])
  assert 50 < inside.any(1).sum() < 950
  assert np.mean(inside != expected) < 1e-3  # only grid points within rounding of the boundary
  hit = t_in <= t_out
  np.testing.assert_allclose(np.linalg.norm(normal[hit], axis=-1), 1.0, atol=1e-9)
  entry = origins[hit] + t_in[hit, None] * directions[hit]
  assert np.all(np.sum(normal[hit] * directions[hit], -1) <= 1e-9)  # rays enter, not exit
  assert np.all(np.isfinite(entry))


_rays_to = helpers.rays_to


def _top_of_red_sphere(scene_name):
  scene = scenes.get_scene(scene_name)
  light = np.asarray(scene.light.direction) / np.linalg.norm(scene.light.direction)
  mirror = np.array([-light[0], -light[1], light[2]])  # reflection of the light about +z
  origins, dirs = _rays_to(np.array([0.0, 0.0, 0.5]), [mirror, [0.5, 0.6, 0.7]])
  out = simulator.trace_rays(scene, origins, dirs, near=0.1, far=10.0)
  np.testing.assert_allclose(out["depth"], 1.5, atol=1e-9)  # 3 / |d| = 1.5: both hit the point
  return out["rgb"]


def test_diffuse_point_looks_the_same_from_two_directions():
  rgb = _top_of_red_sphere("diffuse")
  np.testing.assert_allclose(rgb[0], rgb[1], atol=1e-12)


def test_glossy_point_looks_different_from_two_directions():
  rgb = _top_of_red_sphere("glossy")
  assert np.all(rgb[0] - rgb[1] > 0.15)  # the mirror direction sees the highlight


def _spy(monkeypatch, name):
  calls = []
  original = getattr(simulator, name)
  monkeypatch.setattr(simulator, name, lambda *a, **k: calls.append(1) or original(*a, **k))
  return calls


@pytest.mark.parametrize("function,computed_for", [("specular", {"glossy", "detail", "multiscale"}),
                                                   ("trace_medium", {"fog"}),
                                                   ("_shadow", {"glossy", "fog", "white",
                                                                "forward"})])
def test_only_declared_effects_are_computed(monkeypatch, function, computed_for):
  pose = rays_lib.pose_spherical(30.0, -40.0, 4.0)
  for name in scenes.SCENES:
    calls = _spy(monkeypatch, function)
    scenes.render_view(scenes.get_scene(name), pose, 20, 20, 27.8)
    assert bool(calls) == (name in computed_for), (function, name)


def test_effect_declaration_is_checked():
  with pytest.raises(ValueError, match="view_dependent"):
    dataclasses.replace(scenes.get_scene("glossy"), effects=scenes.Effects(shadows=True))
  with pytest.raises(ValueError, match="participating_medium"):
    dataclasses.replace(scenes.get_scene("diffuse"),
                        effects=scenes.Effects(participating_medium=True))
  assert scenes.get_scene("fog").effects.names() == {"participating_medium", "shadows"}


def _fog_reference(scene, origins, directions, near, far, steps=20000):
  """Midpoint-rule quadrature of the emission-absorption integral, one ray at a time; the
  opaque surface comes from the same scene rendered without its medium."""
  solid = dataclasses.replace(scene, medium=None, effects=dataclasses.replace(
      scene.effects, participating_medium=False))
  surf = simulator.trace_rays(solid, origins, directions, near, far)
  fog, out = scene.medium, {"rgb": [], "acc": [], "depth": []}
  for o, d, s_acc, s_depth, s_rgb in zip(origins, directions, surf["acc"], surf["depth"],
                                         surf["rgb"]):
    end = s_depth if s_acc > 0 else far
    dt = (end - near) / steps
    t = near + (np.arange(steps) + 0.5) * dt
    inside = np.linalg.norm(o + t[:, None] * d - fog.shape.center, axis=-1) <= fog.shape.radius
    alpha = 1.0 - np.exp(-fog.density * np.linalg.norm(d) * inside * dt)
    trans = np.cumprod(np.concatenate([[1.0], 1.0 - alpha]))
    w = trans[:-1] * alpha
    w_surf = trans[-1] * s_acc
    acc = w.sum() + w_surf
    out["acc"].append(acc)
    out["rgb"].append(w.sum() * np.asarray(fog.color) + w_surf * s_rgb)  # background is black
    out["depth"].append((np.sum(w * t) + w_surf * s_depth) / acc if acc > 0 else far)
  return {k: np.array(v) for k, v in out.items()}


def test_fog_matches_brute_force_quadrature():
  scene = scenes.get_scene("fog")
  o, d = rays_lib.get_rays(12, 12, 16.7, rays_lib.pose_spherical(20.0, -30.0, 4.0))
  o, d = np.asarray(o, np.float64).reshape(-1, 3), np.asarray(d, np.float64).reshape(-1, 3)
  exact = simulator.trace_rays(scene, o, d, 2.0, 6.0)
  ref = _fog_reference(scene, o, d, 2.0, 6.0)
  partial = (exact["acc"] > 0.05) & (exact["acc"] < 0.95)
  assert partial.sum() >= 5 and (exact["acc"] == 1.0).sum() >= 5  # fog alone and surfaces
  for key in ("acc", "rgb", "depth"):
    np.testing.assert_allclose(exact[key], ref[key], atol=1e-3, err_msg=key)


def test_white_scene_empty_pixels_are_exactly_white():
  ds = scenes.make_dataset("white", num_views=2, height=32, width=32, focal=44.4)
  empty = ds.accs == 0.0
  assert 0 < empty.sum() < empty.size
  np.testing.assert_array_equal(ds.images[empty], 1.0)
  np.testing.assert_array_equal(ds.depths[empty], 6.0)


def test_make_dataset_matches_render_view_and_is_deterministic():
  ds = scenes.make_dataset("glossy", num_views=3, height=24, width=20, focal=30.0,
                           pixel_center=0.5, seed=3)
  again = scenes.make_dataset("glossy", num_views=3, height=24, width=20, focal=30.0,
                              pixel_center=0.5, seed=3)
  np.testing.assert_array_equal(ds.images, again.images)
  view = scenes.render_view(scenes.get_scene("glossy"), ds.poses[2], 24, 20, 30.0, 0.5)
  np.testing.assert_allclose(view["rgb"], ds.images[2], atol=1e-4)
  np.testing.assert_allclose(view["depth"], ds.depths[2], atol=1e-4)
  assert ds.images.shape == (3, 24, 20, 3) and ds.images.dtype == np.float32
  centres = ds.poses[:, :3, 3]
  np.testing.assert_allclose(np.linalg.norm(centres, axis=-1), 4.0, rtol=1e-6)
  assert np.all(centres[:, 2] > 0)  # upper hemisphere


def test_whole_scene_is_in_view():
  ds = scenes.make_dataset("white", num_views=10, height=50, width=50, focal=69.44)
  border = np.concatenate([ds.accs[:, 0], ds.accs[:, -1], ds.accs[:, :, 0], ds.accs[:, :, -1]])
  assert border.max() == 0.0


def test_unknown_scene_lists_valid_names():
  with pytest.raises(ValueError, match="diffuse, exposure, fog, forward, garden, glossy, "
                                       "landmark, landmark_sfm, multiscale, perturbed"):
    scenes.get_scene("lego")


def test_forward_scene_is_an_llff_like_capture():
  ds = scenes.make_dataset("forward", num_views=6, height=24, width=24, focal=33.3, seed=1)
  np.testing.assert_array_equal(ds.poses[:, :3, :3], np.broadcast_to(np.eye(3), (6, 3, 3)))
  centres = ds.poses[:, :3, 3]
  assert np.all(np.abs(centres[:, :2]) <= 0.3) and np.all(centres[:, 2] == 0.0)
  assert np.ptp(centres[:, 0]) > 0.1 and np.ptp(centres[:, 1]) > 0.1  # parallax
  np.testing.assert_array_equal(ds.accs, 1.0)  # every ray hits something, as in a real capture
  assert (ds.near, ds.far) == (scenes.get_scene("forward").near, scenes.get_scene("forward").far)
  assert 0.85 * ds.depths.min() <= ds.near <= ds.depths.min()  # ~0.9x the nearest depth
  assert ds.depths.max() <= ds.far <= 1.15 * ds.depths.max()  # ~1.1x the wall's
  assert ds.forward_facing and ds.background == (0.0, 0.0, 0.0)
  hemisphere = scenes.make_dataset("white", num_views=1, height=4, width=4, focal=5.6)
  assert (hemisphere.near, hemisphere.far, hemisphere.forward_facing) == (2.0, 6.0, False)
  assert hemisphere.background == (1.0, 1.0, 1.0)


def test_checkered_wall_alternates_albedo():
  scene = scenes.get_scene("forward")
  wall = scene.objects[0].material
  xy = np.array([[1.6, 1.6], [2.1, 1.6], [1.9, 1.9]])  # squares (3, 3), (4, 3), (3, 3) of 0.5
  origins = np.concatenate([xy, np.zeros((3, 1))], -1)
  out = simulator.trace_rays(scene, origins, np.tile([0.0, 0.0, -1.0], (3, 1)), 1.0, 6.0)
  np.testing.assert_allclose(out["depth"], 5.0)
  np.testing.assert_allclose(out["rgb"][2], out["rgb"][0], atol=1e-12)
  np.testing.assert_allclose(out["rgb"][1] / out["rgb"][0],
                             np.divide(wall.albedo2, wall.albedo), rtol=1e-9)  # same lighting


def _room_exit(o, d):
  """Where rays o + t d (float64 [R, 3]) leave the garden's room: the box [-16, 16]^2 x
  [-0.6, 10] (inner faces of the walls, the ground's top and the ceiling), from inside it."""
  lo = np.array([-garden.WALL, -garden.WALL, garden.GROUND_Z])
  hi = np.array([garden.WALL, garden.WALL, garden.SKY_Z])
  safe = np.where(d == 0.0, 1.0, d)
  t = np.where(d > 0, (hi - o) / safe, np.where(d < 0, (lo - o) / safe, np.inf))
  return t.min(-1)


def test_garden_depth_is_the_analytic_intersection():
  scene = scenes.get_scene("garden")
  pose = rays_lib.pose_spherical(90.0, -10.0, 4.0)  # at +x, 10° up, looking at the centre
  out = scenes.render_view(scene, pose, 40, 40, 55.6, 0.5, scene.near, scene.far)
  o, d = (np.asarray(a, np.float64) for a in rays_lib.get_rays(40, 40, 55.6, pose, 0.5))
  # The top rows pass above everything in the middle and miss the trees: they end on the far
  # walls (the ceiling is too high to see), at the room's exit.
  np.testing.assert_allclose(out["depth"][:4], _room_exit(o[:4], d[:4]), rtol=1e-6)
  assert np.all(out["depth"][:4] > 12.0)
  # The bottom row's middle ends on the ground (z = -0.6) between the camera and the disc.
  bottom = (slice(-1, None), slice(15, 25))
  t_ground = (garden.GROUND_Z - o[bottom][..., 2]) / d[bottom][..., 2]
  np.testing.assert_allclose(out["depth"][bottom], t_ground, rtol=1e-6)
  # The centre pixel ends on the red sphere (radius 0.5 at the origin): |o + t d|^2 = 0.25.
  oc, dc = o[20, 20], d[20, 20]
  a, b, c = dc @ dc, oc @ dc, oc @ oc - 0.25
  np.testing.assert_allclose(out["depth"][20, 20], (-b - np.sqrt(b * b - a * c)) / a, rtol=1e-6)
  assert np.all(out["acc"] == 1.0)


def test_garden_is_opaque_everywhere():
  ds = scenes.make_dataset("garden", num_views=6, height=32, width=32, focal=44.4)
  np.testing.assert_array_equal(ds.accs, 1.0)
  assert ds.depths.max() < ds.far and ds.depths.min() > ds.near
  elevation = np.degrees(np.arcsin(ds.poses[:, 2, 3] / 4.0))
  assert np.all((elevation >= 2.0) & (elevation <= 20.0))  # the scene's low orbit
  # Rays in every direction (axis-aligned ones included) from points around the middle: the
  # room is closed, so every ray ends on a surface inside it.
  rng = np.random.default_rng(0)
  directions = np.concatenate([rng.normal(size=(2000, 3)), np.eye(3), -np.eye(3)])
  origins = rng.uniform(-3.0, 3.0, (len(directions), 3)) * [1.0, 1.0, 0.0] + [0.0, 0.0, 5.0]
  out = simulator.trace_rays(scenes.get_scene("garden"), origins, directions, 0.0, 1e3)
  np.testing.assert_array_equal(out["acc"], 1.0)
  points = origins + out["depth"][:, None] * directions
  assert np.all(np.abs(points) <= [garden.WALL + 1e-6, garden.WALL + 1e-6, garden.SKY_Z + 1e-6])


def test_garden_has_content_beyond_the_inner_region():
  ds = scenes.make_dataset("garden", num_views=6, height=32, width=32, focal=44.4)
  o, d = zip(*(rays_lib.get_rays(32, 32, 44.4, pose, 0.5) for pose in ds.poses))
  points = np.asarray(o, np.float64) + ds.depths[..., None] * np.asarray(d, np.float64)
  radius = np.linalg.norm(points, axis=-1)
  assert np.mean(radius > 2.0) > 0.3  # much of every view lies beyond radius 2
  assert np.mean(radius < 1.2) > 0.2  # and the middle is there too
  assert np.any((radius > 4.0) & (radius < 8.5))  # the trees, the shed, the boulder
  assert np.mean(radius > garden.WALL) > 0.05  # the walls
  assert scenes.get_scene("garden").effects.names() == {"unbounded"}


def test_unbounded_declaration_is_checked():
  far = scenes.Object(Sphere((0.0, 0.0, -5.0), 0.5), scenes.Material((0.5, 0.5, 0.5)))
  with pytest.raises(ValueError, match="unbounded"):
    scenes.Scene("far", (far,), scenes.Effects())
  with pytest.raises(ValueError, match="unbounded"):
    dataclasses.replace(scenes.get_scene("diffuse"), effects=scenes.Effects(unbounded=True))
  assert scenes.Scene("far", (far,), scenes.Effects(unbounded=True)).effects.unbounded
  # The forward scene's back wall (16 x 16 at depth 5) reaches beyond the inner cube too.
  unbounded = {n for n, scene in scenes.SCENES.items() if scene.effects.unbounded}
  assert unbounded == {"forward", "garden", "landmark", "landmark_sfm"}


@pytest.mark.parametrize("shape", [Sphere((0.3, -1.2, 0.5), 0.6),
                                   Box((-0.4, 0.2, 1.1), (0.8, 0.5, 1.3)),
                                   Cylinder((0.2, 0.9, -0.3), 0.5, 1.6),
                                   scenes.Rod((0.1, -0.2, 0.3), (0.9, 0.4, -1.1), 0.05)])
def test_extent_is_the_largest_coordinate(shape):
  # Brute force: the largest |coordinate| of points on a grid that lie inside the solid (on a
  # ray through each grid row, by the shape's own interval), within a grid step.
  g = np.linspace(-3.0, 3.0, 301)
  y, z = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
  rows = []
  for perm in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # rows along each axis
    origins = np.zeros((len(y), 3))
    origins[:, perm[1]], origins[:, perm[2]] = y, z
    origins[:, perm[0]] = -10.0
    directions = np.zeros_like(origins)
    directions[:, perm[0]] = 1.0
    t_in, t_out, _ = shape.intersect(origins, directions)
    hit = t_in <= t_out
    ends = np.stack([t_in[hit], t_out[hit]], -1) - 10.0  # the row's coordinate along the axis
    rows.append(max(np.abs(ends).max(), np.abs(origins[hit][:, list(perm[1:])]).max()))
  brute = max(rows)
  got = scene_lib.extent(shape)
  if isinstance(shape, scenes.Rod):  # padded by the radius in every direction: a bound
    assert brute - 0.02 <= got <= brute + shape.radius + 0.02
  else:
    assert got == pytest.approx(brute, abs=0.02)
