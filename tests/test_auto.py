"""--config=auto: each rule of characterise.py on a generated capture with a known answer, the
user's flag winning, too few cameras, and auto against the hand-written configs/scenes/*.py."""

import dataclasses

import numpy as np
import pytest

from nerf_jax import auto, characterise, cli, config_lib, experiment, scenes
from nerf_jax.data import loaders
from nerf_jax.data.dataset import Dataset
from nerf_jax.scenes import photos


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
                                             "unbounded": False, "appearance": False}
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


def test_cameras_around_a_frame_filling_scene_are_unbounded():
  assert _found(_capture(AROUND)) == {"background": False, "forward": False, "unbounded": True,
                                      "appearance": False}
  assert not _found(_capture(AHEAD))["unbounded"]


def test_per_photo_gains_call_for_appearance_codes():
  train, _ = loaders.load_dataset({"scene": "diffuse", "num_views": 40, "image_size": 16})
  assert not _found(train)["appearance"]
  gained = dataclasses.replace(train, images=photos.with_gains(train.images,
                                                               photos.gains(len(train))))
  assert _found(gained)["appearance"]
  assert characterise.colour_spread(gained) > 2 * characterise.colour_spread(train)


def _auto(scene, capsys=None, **fields):
  config = config_lib.load("auto")
  config.data.scene, config.data.image_size, config.data.num_views = scene, 24, 40
  for name, value in fields.items():
    section, field = name.split("__")
    if section == "auto":
      config[f"auto_{field}"] = value
    else:
      config[section][field] = value
  train, _ = loaders.load_dataset(config.data)
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
  data, appearance codes."""
  hand = config_lib.load(f"scenes/{scene}")
  auto = _auto(scene)
  expressed = lambda c: (c.data.ndc, c.data.background, c.data.scene_bound == -1,
                         c.model.appearance_dims > 0)
  assert expressed(auto) == expressed(hand)
  assert auto.auto_decisions and not auto.auto


def test_the_command_line_names_the_fields_it_sets():
  argv = ["train.py", "--config=auto", "--config.data.ndc=False", "--workdir=w",
          "--config.train.max_steps=3"]
  assert cli.override_names(argv) == ("data.ndc", "train.max_steps")
