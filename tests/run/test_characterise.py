"""--config=auto: each rule of characterise.py on a generated capture with a known answer, the
user's flag winning, too few cameras, and auto against the hand-written configs/scenes/*.py."""

import dataclasses

import numpy as np
import pytest

from nerf_jax import cli
from nerf_jax.cameras import rays
from nerf_jax.data import loaders, scenes
from nerf_jax.run import builders, config_lib
from nerf_jax.run.auto import auto, characterise
from nerf_jax.run.auto.rules import cones, large_objects, transients
from nerf_jax.cameras.cameras import Cameras
from nerf_jax.data.dataset import Dataset
from nerf_jax.data.scenes import photos
from tests.helpers import load_data

# auto's choices as on a CPU, also when the suite runs on a GPU (conftest.cpu_decisions).
pytestmark = pytest.mark.usefixtures("cpu_decisions")


def _capture(poses, accs=None, images=None):
  """A capture of `poses` with flat grey 8 x 8 photos (or `images`) and opacity `accs`."""
  images = np.full((len(poses), 8, 8, 3), 0.5, np.float32) if images is None else images
  return Dataset(images, np.asarray(poses, np.float32), (8.0, 8.0, 4.0, 4.0), accs=accs)


def _found(dataset):
  return {d.name: d.found for d in characterise.decide(dataset)}


AROUND = scenes.random_poses(20, seed=1)  # cameras on a hemisphere looking at the origin
AHEAD = scenes.forward_poses(20, seed=1)  # LLFF-like: all looking down -z


def test_opacity_with_empty_pixels_is_an_object_on_a_background():
  accs = np.zeros((20, 8, 8), np.float32)
  accs[:, 2:6, 2:6] = 1.0  # the subject in the middle, empty around it
  assert _found(_capture(AROUND, accs)) == {"background": True, "forward": False,
                                             "unbounded": False, "appearance": False,
                                             "view_dependence": None,  # no depth: not measured
                                             "scales": False}
  full = np.ones((20, 8, 8), np.float32)  # opacity known but nothing empty: no background
  assert not _found(_capture(AROUND, full))["background"]


def test_cameras_within_a_cone_are_forward_facing():
  assert _found(_capture(AHEAD))["forward"]
  # Turned by 25° (inside the 30° cone) and by 35° (outside): the rule's edge.
  for degrees, expected in ((25.0, True), (35.0, False)):
    turned = np.array(AHEAD)
    turned[0, :3, :3] = photos.rotation(np.radians([degrees, 0.0, 0.0]))
    assert characterise.cone_degrees(turned) == pytest.approx(degrees * 19 / 20, abs=1.5)
    assert _found(_capture(turned))["forward"] == expected


def test_forward_facing_cameras_stand_near_one_plane():
  """NDC starts every ray on the near plane: cameras within the cone but far apart along their
  mean direction (tourists on the steps and across the square) are not forward-facing."""
  dirs = -np.asarray(AHEAD)[:, :3, 2]
  mean = dirs.mean(0) / np.linalg.norm(dirs.mean(0))
  flat = np.array(AHEAD, np.float64)
  flat[:, :3, 3] -= np.outer(flat[:, :3, 3] @ mean, mean)  # every centre on one plane across it
  near = _capture(AHEAD).near
  for share, expected in ((0.4, True), (0.6, False)):  # either side of FORWARD_DEPTH_SHARE
    moved = flat.copy()
    moved[0, :3, 3] += share * near * mean  # camera 0 steps forward along the mean direction
    assert characterise.depth_spread(moved) == pytest.approx(share * near, abs=1e-5)
    assert _found(_capture(moved))["forward"] == expected


def test_cameras_around_a_frame_filling_scene_are_unbounded():
  assert _found(_capture(AROUND)) == {"background": False, "forward": False, "unbounded": True,
                                      "appearance": False, "view_dependence": None,
                                      "scales": False}
  assert not _found(_capture(AHEAD))["unbounded"]


def test_the_focus_point_is_where_the_axes_meet():
  # Cameras on a hemisphere of radius 4 looking at (0.3, -0.2, 0.1): the point, to rounding.
  target = np.array([0.3, -0.2, 0.1])
  poses = np.array(AROUND, np.float64)
  poses[:, :3, 3] += target
  np.testing.assert_allclose(characterise.focus_point(poses, 2.0, 6.0), target, atol=1e-6)
  # Parallel axes meet nowhere: the cameras' mean centre, sqrt(near·far) ahead.
  ahead = np.array(AHEAD, np.float64)
  ahead[:, :3, :3] = np.eye(3)
  want = ahead[:, :3, 3].mean(0) + np.array([0.0, 0.0, -3.0])
  np.testing.assert_allclose(characterise.focus_point(ahead, 1.0, 9.0), want, atol=1e-9)


def test_cameras_at_several_distances_and_resolutions_call_for_cones():
  # The footprint, distance over focal length, written here: cameras at distance 4 with focal
  # 8 see 0.5 units per pixel at the centre. Halving the focal of a third of them (an image at
  # half the resolution) or doubling their distance both give a 2x spread; 1.5x is below it.
  poses = np.array(AROUND, np.float64)
  base = _capture(poses)
  np.testing.assert_allclose(characterise.pixel_footprints(base),
                             np.linalg.norm(poses[:, :3, 3], axis=1) / 8.0, rtol=1e-6)
  assert characterise.footprint_spread(base) == pytest.approx(1.0)
  assert not _found(base)["scales"]
  for factor, expected in ((2.0, True), (1.5, False)):
    far = poses.copy()
    far[::3, :3, 3] *= factor
    assert characterise.footprint_spread(_capture(far)) == pytest.approx(factor, rel=1e-6)
    assert _found(_capture(far))["scales"] == expected
  small = dataclasses.replace(base, image_cameras=Cameras.stack(
      [(8, 8, (4.0 if i % 3 == 0 else 8.0,) * 2 + (4.0, 4.0)) for i in range(len(poses))]))
  assert characterise.footprint_spread(small) == pytest.approx(2.0, rel=1e-6)
  assert _found(small)["scales"]


def test_auto_turns_cones_on_for_the_multiscale_scene_and_off_for_one_scale(capsys):
  multi = _auto("multiscale")
  assert multi.model.encoding == "grid" and multi.model.grid.antialias
  assert multi.model.grid.multisample == cones.ANTIALIAS_MULTISAMPLE
  assert multi.render.march == config_lib.load("fast").render.march  # marching reads cones
  out = capsys.readouterr().out
  assert "auto: cameras at several scales: cones" in out
  for scene in ("diffuse", "forward", "garden"):
    assert not _auto(scene).model.grid.antialias
  assert "auto: one scale: pixel footprints" in capsys.readouterr().out


def test_cone_effects_follow_the_encoding():
  config = config_lib.load("default")
  assert cones.cone_effects(config) == {"model.encoding": "ipe"}
  config.model.encoding = "hash"
  assert cones.cone_effects(config)["model.hash.antialias"]
  config.model.encoding = "tensorf"
  assert cones.cone_effects(config) == {}
  assert "no anti-aliased form" in cones.cone_summary(config)


def test_per_photo_gains_call_for_appearance_codes():
  train, _ = load_data({"scene": "diffuse", "num_views": 40, "image_size": 16})
  assert not _found(train)["appearance"]
  gained = dataclasses.replace(train, images=photos.with_gains(train.images,
                                                               photos.gains(len(train))))
  assert _found(gained)["appearance"]
  assert characterise.colour_spread(gained) > 2 * characterise.colour_spread(train)


def test_photos_at_many_zooms_are_a_collection_taken_by_many():
  """Cameras of their own whose focal lengths (over the image's diagonal) differ 1.5x or more:
  many lenses and zooms. The same looks, so only the zooms can call for the codes."""
  for focals, sizes, expected in (([8.0, 10.0, 12.0, 16.0] * 5, [8] * 20, True),
                                  ([8.0, 9.0, 10.0, 11.0] * 5, [8] * 20, False),  # 1.375x
                                  ([8.0, 16.0, 4.0, 2.0] * 5, [8, 16, 4, 2] * 5, False)):  # scales
    cams = Cameras.stack([(s, s, (f, f, s / 2, s / 2)) for f, s in zip(focals, sizes)])
    images = [np.full((s, s, 3), 0.5, np.float32) for s in sizes]
    data = Dataset(images, np.asarray(AROUND, np.float32), cams.camera(0)[2], image_cameras=cams)
    spread = max(focals[:4]) / min(focals[:4]) if sizes[0] == sizes[1] else 1.0
    assert characterise.zoom_spread(data) == pytest.approx(spread)
    assert _found(data)["appearance"] == expected


def test_highlights_that_move_call_for_view_dependence():
  """glossy's Blinn-Phong highlights against diffuse's Lambertian objects (the same scene
  without them), also with per-photo gains, which are exposure, not highlights."""
  load = lambda scene: load_data({"scene": scene, "num_views": 40,
                                             "image_size": 24})[0]
  glossy, diffuse = load("glossy"), load("diffuse")
  assert _found(glossy)["view_dependence"] and not _found(diffuse)["view_dependence"]
  gained = dataclasses.replace(diffuse, images=photos.with_gains(diffuse.images,
                                                                 photos.gains(len(diffuse))))
  assert not _found(gained)["view_dependence"]
  assert characterise.highlight_excess(glossy) > 1.5 * characterise.highlight_excess(gained)
  # Without depth the points cannot be matched: not measured.
  assert _found(dataclasses.replace(glossy, depths=None))["view_dependence"] is None


def _plane_capture(lit_views=(), size=32):
  """The square |x|, |y| <= 1 of the plane z = 0, grey 0.4, under 12 cameras around it (exact
  z-depth and opacity per pixel); in `lit_views` its part x > 0.4 (30% of it) looks 0.8."""
  poses = scenes.random_poses(12, seed=3)
  intrinsics = (1.8 * size, 1.8 * size, size / 2, size / 2)  # the square fills most of a view
  cam = np.asarray(rays.pixel_directions(size, size, *intrinsics, 0.5), np.float64)
  images = np.zeros((12, size, size, 3), np.float32)
  depths = np.full((12, size, size), 100.0, np.float32)
  accs = np.zeros((12, size, size), np.float32)
  for view, pose in enumerate(poses):
    dirs = cam @ pose[:3, :3].T  # z-depth t: the point is origin + t·dirs (cam's z = -1)
    t = -pose[2, 3] / np.minimum(dirs[..., 2], -1e-9)
    hit = pose[:3, 3] + t[..., None] * dirs
    inside = (dirs[..., 2] < 0) & (np.abs(hit[..., 0]) <= 1) & (np.abs(hit[..., 1]) <= 1)
    grey = np.where((hit[..., 0] > 0.4) & (view in lit_views), 0.8, 0.4)
    images[view] = np.where(inside, grey, 0.0)[..., None]
    depths[view] = np.where(inside, t, 100.0)
    accs[view] = inside
  return Dataset(images, np.asarray(poses, np.float32), intrinsics, depths=depths, accs=accs)


def test_a_plane_lit_in_two_views_has_a_highlight_and_in_one_view_not():
  """By hand: Lambertian, every view sees the same grey (excess 0); lit in two views, a point
  of the lit part has second-brightest/median = (0.8 + 0.05)/(0.4 + 0.05) and it is more than
  a fifth of the points; lit in one view, the second brightest is grey again."""
  assert characterise.highlight_excess(_plane_capture()) == pytest.approx(0.0, abs=1e-12)
  assert characterise.highlight_excess(_plane_capture((2, 7))) == pytest.approx(
      np.log(0.85 / 0.45), rel=1e-6)
  assert characterise.highlight_excess(_plane_capture((2,))) == pytest.approx(0.0, abs=1e-12)


def test_a_view_whose_depth_is_nearer_does_not_see_the_point():
  """An occluder in front of the plane in one view: its pixels are not the plane's points."""
  flat = _plane_capture()
  points = np.array([[0.0, 0.0, 0.0], [0.5, -0.5, 0.0]])
  log_luminance = np.log(np.asarray(flat.images, np.float64).mean(-1) + 0.05)
  seen = characterise._seen_from(flat, points, log_luminance)
  assert np.isfinite(seen[:, 5]).all() and np.isfinite(seen).sum() >= 18  # of 24
  np.testing.assert_allclose(seen[np.isfinite(seen)], np.log(0.45), rtol=1e-6)  # float32 0.4
  occluded = np.array(flat.depths)
  occluded[5] *= 0.5
  behind = characterise._seen_from(dataclasses.replace(flat, depths=occluded), points,
                                   log_luminance)
  assert np.isnan(behind[:, 5]).all()
  np.testing.assert_array_equal(np.delete(behind, 5, axis=1), np.delete(seen, 5, axis=1))


def test_nanmedian_matches_numpys():
  rng = np.random.default_rng(0)
  a = rng.normal(size=(7, 5))
  a[rng.random(a.shape) < 0.4] = np.nan
  a[:, 2] = np.nan  # a column with nothing finite
  with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
    expected = np.nanmedian(a, axis=0)
  np.testing.assert_array_equal(characterise._nanmedian(a, axis=0), expected)


def test_large_images_at_several_scales_keep_detail_py_with_its_levels_weighted(monkeypatch,
                                                                                  capsys):
  monkeypatch.setattr(large_objects, "LARGE_IMAGES", 16)  # the 24 px scene counts as large
  # Not what this test asks: the transients' warm-up (half a minute a call) is left out.
  monkeypatch.setattr(transients, "transient_effects", lambda *a: ({}, "no transients: not asked"))
  # Its sparse views differ in mean colour (the appearance rule fires): detail.py, whose density
  # grids take appearance codes too; with the codes turned off, detail.py without them.
  with_codes = _auto("multiscale")
  assert with_codes.auto_decisions[-1] == "representation: configs/detail.py"
  assert with_codes.model.appearance_dims > 0
  assert builders.make_ray_renderer(with_codes).field.uses_images  # it builds, with codes
  decided = _auto("multiscale", model__appearance_dims=0,
                  auto__flags=("model.appearance_dims",))
  assert "representation: configs/detail.py" in decided.auto_decisions
  assert decided.model.appearance_dims == 0
  assert (decided.model.grid.antialias, decided.model.grid.multisample,
          decided.render.march) == (True, cones.ANTIALIAS_MULTISAMPLE,
                                    config_lib.load("detail").render.march)
  assert decided.model.grid.density_resolutions == config_lib.load(
      "detail").model.grid.density_resolutions
  assert builders.make_ray_renderer(decided).field.cones == (
      "multisamples" if cones.ANTIALIAS_MULTISAMPLE else "scales")
  assert "auto: cameras at several scales: cones" in capsys.readouterr().out


def _auto(scene, capsys=None, **fields):
  config = config_lib.load("auto")
  config.data.scene, config.data.image_size, config.data.num_views = scene, 24, 40
  for name, value in fields.items():
    section, field = name.split("__")
    if section == "auto":
      config[f"auto_{field}"] = value
    else:
      config[section][field] = value
  train, _ = load_data(config.data)
  return auto.auto_config(config, train)


def test_too_few_cameras_use_the_capture_defaults(capsys):
  config = config_lib.load("auto")
  decided = auto.auto_config(config, _capture(AROUND[:2]))
  out = capsys.readouterr().out
  assert "2 cameras are too few to characterise" in out and "configs/capture.py" in out
  assert decided.data.scene_bound == config_lib.load("capture").data.scene_bound
  assert not decided.auto and decided.auto_decisions[0].startswith("2 cameras")


def test_the_users_flag_wins_with_one_line(capsys):
  decided = _auto("forward", data__ndc=False, auto__flags=("data.ndc",))  # as nerf-train sets
  out = capsys.readouterr().out
  assert not decided.data.ndc
  assert "auto: data.ndc=False from your flags, not auto's True" in out.splitlines()
  assert len([l for l in out.splitlines() if "from your flags" in l]) == 1


HAND_WRITTEN = ["diffuse", "glossy", "fog", "white", "forward", "garden", "exposure", "perturbed",
                "detail"]


@pytest.mark.parametrize("scene", HAND_WRITTEN)
def test_auto_picks_what_the_scene_config_switches_on(scene):
  """The effects both express: NDC, the background colour, an unbounded scene's box from the
  data, appearance codes, view dependence."""
  hand = config_lib.load(f"scenes/{scene}")
  auto = _auto(scene)
  # A hand-written config's data.background 'auto' is the built-in scenes' black.
  colour = lambda c: (loaders.auto_background(c.data.path)[0]
                      if loaders.is_auto(c.data.background) else c.data.background)
  expressed = lambda c: (c.data.ndc, colour(c), c.data.scene_bound == -1,
                         c.model.appearance_dims > 0, c.model.view_dependent,
                         c.loss.robust.weight > 0)
  assert expressed(auto) == expressed(hand)
  assert auto.auto_decisions and not auto.auto


def test_auto_leaves_the_passers_by_of_crowd_out(capsys):
  # At 48 px (the warm-up's size; at 24 px the passers-by are a few pixels) auto measures the
  # transients after its warm-up and switches the trimmed loss on, as configs/scenes/crowd.py.
  hand = config_lib.load("scenes/crowd")
  decided = _auto("crowd", data__image_size=48)
  for field in ("train.batching", "train.patch_size", "loss.colour.weight", "loss.robust.weight"):
    section, name = field.split(".", 1)
    assert decided[section][name] == hand[section][name], field
  # ... and what follows from the switch: patches of 16, the colour term aside.
  assert builders.batch_settings(decided) == builders.batch_settings(hand)
  assert builders.batch_settings(decided).batching == "patches"
  assert decided.model.appearance_dims > 0 and decided.eval.appearance == "left_half"
  line = next(l for l in capsys.readouterr().out.splitlines() if "transients" in l)
  assert line.startswith("auto: transients left out: RobustNeRF's trimmed loss on 16 x 16")
  share = float(line.split(": ")[-1].split("%")[0]) / 100
  assert share > transients.TRANSIENT_SHARE


def test_the_command_line_names_the_fields_it_sets():
  argv = ["train.py", "--config=auto", "--config.data.ndc=False", "--workdir=w",
          "--config.train.max_steps=3"]
  assert cli.override_names(argv) == ("data.ndc", "train.max_steps")
