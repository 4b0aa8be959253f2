"""The data formats' registry (data/formats/): one record per format, named as its module, tried
in one order; detection, the 'auto' background and the photos data.factor downscales all come
from it, as the if-chains they replaced decided them."""

import dataclasses
import itertools
import os
import sys

import numpy as np
import pytest

from nerf_jax.data import export, formats, loaders
from nerf_jax.data.dataset import DataError
from nerf_jax.run.auto import resolution
from tests import helpers

# What marks each folder format, in the order load_dataset tried them before the registry.
MARKERS = {"nerfstudio": "transforms.json", "multiscale": "metadata.json",
           "blender": "transforms_train.json", "llff": "poses_bounds.npy",
           "colmap": "sparse/0/cameras.txt"}


def reference_format(path):
  """The format the former if-chain of load_dataset read `path` as (None: unknown), written
  out as it was; `path` exists or is ''."""
  has = lambda name: os.path.isfile(os.path.join(path, name))
  if not path:
    return "scene"
  if os.path.isfile(path) and path.endswith(".npz"):
    return "npz"
  if path.endswith("transforms.json") or has("transforms.json"):
    return "nerfstudio"
  for name in ("multiscale", "blender", "llff"):
    if has(MARKERS[name]):
      return name
  if os.path.isdir(path) and any(has(f"{d}/cameras.{e}") for d in ("sparse/0", "sparse",
                                                                    "colmap/sparse/0")
                                 for e in ("bin", "txt")):
    return "colmap"
  return None


def test_every_built_in_is_one_record_named_as_its_module():
  assert formats.names() == ("scene", "npz", "nerfstudio", "multiscale", "blender", "llff",
                             "colmap")
  for name in formats.names():
    record = formats.lookup(name)
    assert isinstance(record, formats.Format)
    assert record.name == name == formats.FORMATS[name].rsplit(".", 1)[-1]


def test_every_mix_of_marker_files_is_read_as_the_former_if_chain_read_it(tmp_path):
  names = list(MARKERS)
  for k, held in enumerate(itertools.product([False, True], repeat=len(names))):
    folder = tmp_path / f"mix_{k}"
    folder.mkdir()
    for name, present in zip(names, held):
      if present:
        (folder / MARKERS[name]).parent.mkdir(parents=True, exist_ok=True)
        (folder / MARKERS[name]).write_text("")
    record = formats.detect(str(folder))
    assert (record and record.name) == reference_format(str(folder)), sorted(
        n for n, p in zip(names, held) if p)
  (tmp_path / "a.npz").write_bytes(b"")
  (tmp_path / "notes.txt").write_text("")
  (tmp_path / "mix_1" / "transforms.json").write_text("")  # the file itself
  for path in ("", str(tmp_path / "a.npz"), str(tmp_path / "notes.txt"),
               str(tmp_path / "mix_1" / "transforms.json")):
    record = formats.detect(path)
    assert (record and record.name) == reference_format(path), path
  assert formats.detect(str(tmp_path / "missing")) is None  # nothing there: no format's


def test_unknown_data_is_the_one_line_it_was(tmp_path):
  (tmp_path / "notes.txt").write_text("")
  path = str(tmp_path / "notes.txt")
  was = (f"unknown dataset format at {path} (expected a .npz file or a directory with "
         "transforms.json, transforms_train.json, poses_bounds.npy or a COLMAP model in "
         "sparse/0 or sparse or colmap/sparse/0)")
  assert formats.unknown(path) == was
  with pytest.raises(DataError) as info:
    helpers.load_data({"path": path})
  assert str(info.value) == was


def test_auto_background_and_photos_follow_the_format_detected(tmp_path):
  scene = helpers.load_data({"scene": "white", "num_views": 5, "image_size": 8})
  blender = str(tmp_path / "blender")
  export.export_blender(scene[0], blender, split_at=3)  # RGBA PNGs
  assert loaders.auto_background(blender) == formats.lookup("blender").background(blender)
  assert loaders.auto_background(blender)[0] == "white"
  # A folder that also holds transforms.json is read as nerfstudio's: black, its frames' photos.
  (tmp_path / "blender" / "transforms.json").write_text(
      '{"frames": [{"file_path": "train/r_0.png"}, {"file_path": "gone.png"}]}')
  assert loaders.auto_background(blender) == formats.BLACK
  photos = [os.path.join(blender, "train", "r_0.png")]
  assert formats.photo_paths(blender) == photos and os.path.isfile(photos[0])
  llff = tmp_path / "llff"
  (llff / "images").mkdir(parents=True)
  (llff / "poses_bounds.npy").write_bytes(b"")
  for name in ("b.JPG", "a.png", "notes.txt"):
    (llff / "images" / name).write_bytes(b"")
  assert formats.photo_paths(str(llff)) == [str(llff / "images" / n) for n in ("a.png", "b.JPG")]
  for path in ("", str(tmp_path / "missing"), blender + "/train"):
    assert formats.photo_paths(path) is None and loaders.auto_background(path) == formats.BLACK


def test_auto_sizes_the_photos_the_format_names(tmp_path):
  """run/resolution reads the registry's photos: an LLFF folder of 3000 x 2000 photos is
  brought under MAX_SIDE['cpu'] by the smallest integer factor."""
  import imageio.v3 as iio  # pylint: disable=import-outside-toplevel
  folder = tmp_path / "llff"
  (folder / "images").mkdir(parents=True)
  (folder / "poses_bounds.npy").write_bytes(b"")
  iio.imwrite(folder / "images" / "0.png", np.zeros((2000, 3000, 3), np.uint8))
  config = helpers.small_config(base="auto", **{"data.path": str(folder)})
  effects, lines = resolution.factor_effects(config, "cpu")
  assert effects == {"data.factor": -(-3000 // resolution.MAX_SIDE["cpu"])} == {"data.factor": 3}
  assert "3000 x 2000" in lines[0]


def test_register_places_a_format_where_it_is_tried_and_unregister_forgets_it(tmp_path,
                                                                            monkeypatch):
  (tmp_path / "my_fmt.py").write_text(
      "import os\nfrom nerf_jax.data import formats\n"
      "FORMAT = formats.Format('my_fmt', lambda p: os.path.isfile(os.path.join(p, 'x.txt')),\n"
      "                        lambda p, b, s: ('train', 'test'))\n")
  (tmp_path / "no_record.py").write_text("X = 1\n")
  monkeypatch.syspath_prepend(str(tmp_path))
  folder = tmp_path / "data"
  folder.mkdir()
  (folder / "x.txt").write_text("")
  (folder / "poses_bounds.npy").write_text("")
  before = formats.names()
  try:
    formats.register("my_fmt", "my_fmt")
    assert formats.names() == (*before, "my_fmt")
    assert formats.detect(str(folder)).name == "llff"  # tried last: LLFF's marker wins
    formats.register("my_fmt", "my_fmt", before="llff")
    assert formats.names().index("my_fmt") == before.index("llff")
    assert formats.detect(str(folder)).name == "my_fmt"
    assert helpers.load_data({"path": str(folder)}) == ("train", "test")
    with pytest.raises(ValueError, match="no data format 'nope'"):
      formats.register("other", "my_fmt", before="nope")
    formats.register("bad", "no_record")
    with pytest.raises(ValueError, match="data format 'bad': no_record defines no FORMAT"):
      formats.detect(str(tmp_path))  # no built-in's: "bad" is reached
  finally:
    formats.unregister("my_fmt")
    formats.unregister("bad")
    formats.unregister("llff")  # a built-in stays
    for name in ("my_fmt", "no_record"):
      sys.modules.pop(name, None)
  assert formats.names() == before


def test_a_record_is_frozen():
  with pytest.raises(dataclasses.FrozenInstanceError):
    formats.lookup("npz").name = "other"
