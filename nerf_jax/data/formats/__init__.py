"""Data formats as records, found by one rule: data.path is read by the first format of
`FORMATS`, in its order, whose `detect(path)` holds (as multinerf's dataset dict and
nerfstudio's dataparsers name theirs).

A format is one module defining `FORMAT = formats.Format(...)`: how to recognise its data
(`detect`), how to read it into (train, test) Datasets (`load`), what data.background='auto'
means for it (`background`) and which photos data.factor downscales (`photo_paths`, what
--config=auto sizes). Everything that asks what the data at a path is asks here:
loaders.load_dataset, loaders.auto_background, run/auto/resolution.py. A new format is its module
plus its line in FORMATS, at the place it must be tried (docs/extending.md, "Adding a data
format"); `register` adds one from outside the tree for the process that calls it.
"""

import dataclasses
import importlib
import os
from typing import Callable, Optional

# The formats, in the order data.path is tried: name -> the module defining its FORMAT.
FORMATS = {
    "scene": "nerf_jax.data.formats.scene",  # data.path '': a built-in scene
    "npz": "nerf_jax.data.formats.npz",  # a tiny_nerf .npz file
    "nerfstudio": "nerf_jax.data.formats.nerfstudio",  # transforms.json (folder or file)
    # metadata.json: before transforms_train.json, which a converted Blender folder may keep.
    "multiscale": "nerf_jax.data.formats.multiscale",
    "blender": "nerf_jax.data.formats.blender",  # transforms_train.json
    # poses_bounds.npy: before a COLMAP model beside it (LLFF's own data has both).
    "llff": "nerf_jax.data.formats.llff",
    "colmap": "nerf_jax.data.formats.colmap",  # a COLMAP model in sparse/0, sparse, ...
}
_BUILTINS = dict(FORMATS)

# data.background='auto' of data whose format has no rule of its own (or none that applies).
BLACK = ("black", "the convention of data other than Blender's RGBA folders")


@dataclasses.dataclass(frozen=True)
class Format:
  """The record of a data format (one per module, under the name FORMAT).

  name: its registered name (FORMATS).
  detect: path (str: data.path, which exists, or '' for the built-in scenes) -> bool, whether
    the data at `path` is this format's. Only the first format whose detect holds reads it.
  load: (path, background float64 [3], settings data_settings.DataSettings) -> (train, test)
    Datasets; DataError with one line naming the file and field for malformed data.
  background: path -> (name, why) or None: what data.background='auto' means for this
    format's data ('white' and why, for Blender's RGBA images); None (or a rule returning None)
    means `BLACK`.
  photo_paths: path -> [str] or None: the full-size photo files that data.factor downscales
    (--config=auto sizes data.factor from them, run/auto/resolution.py); None: it downscales none.
  expected: how the one line for data of no known format names it: what a folder of it holds
    ('poses_bounds.npy') or, with `file`, the file it is ('a .npz file'); '' = not named.
  file: whether `expected` names a file rather than what a folder holds.
  """
  name: str
  detect: Callable[[str], bool]
  load: Callable
  background: Optional[Callable] = None
  photo_paths: Optional[Callable] = None
  expected: str = ""
  file: bool = False


def register(name, module, before=None):
  """Make the format of `module` (a dotted module path defining FORMAT) known as `name`, tried
  just before the format named `before` (None: after every other). ValueError for an unknown
  `before`."""
  entries = [(n, m) for n, m in FORMATS.items() if n != name]
  others = [n for n, _ in entries]
  if before is not None and before not in others:
    raise ValueError(f"no data format {before!r} to put {name!r} before (formats: "
                     f"{', '.join(others)})")
  at = len(entries) if before is None else others.index(before)
  entries.insert(at, (name, module))
  FORMATS.clear()
  FORMATS.update(entries)


def unregister(name):
  """Forget a format added with `register` (the built-ins stay)."""
  if name not in _BUILTINS:
    FORMATS.pop(name, None)


def names():
  """The formats' names, in the order they are tried."""
  return tuple(FORMATS)


def lookup(name):
  """The record of the format `name`: the FORMAT of its module, imported on first use.
  ValueError naming the module if it cannot be imported or defines no Format."""
  module_path = FORMATS[name]
  try:
    module = importlib.import_module(module_path)
  except ImportError as e:
    raise ValueError(f"data format {name!r}: cannot import {module_path} ({e})") from None
  record = getattr(module, "FORMAT", None)
  if not isinstance(record, Format):
    raise ValueError(f"data format {name!r}: {module_path} defines no FORMAT (a formats.Format "
                     "record: docs/extending.md)")
  return record


def detect(path):
  """The record of the first format (FORMATS' order) whose detect holds for the data at `path`
  (data.path, '' for a built-in scene), or None: no format's, or nothing at `path`."""
  if path and not os.path.exists(path):
    return None
  for name in FORMATS:
    record = lookup(name)
    if record.detect(path):
      return record
  return None


def auto_background(path):
  """(name, why): what data.background='auto' means for the data at `path`: its format's rule,
  else `BLACK` (a path of no known format, or none that exists, included)."""
  record = detect(path)
  rule = record.background(path) if record is not None and record.background else None
  return rule or BLACK


def photo_paths(path):
  """The full-size photo files of the data at `path` that data.factor downscales (its
  format's `photo_paths`), or None: a format that downscales none, or no data at `path`."""
  record = detect(path)
  return record.photo_paths(path) if record is not None and record.photo_paths else None


def unknown(path):
  """The one line for data at `path` that no format detects, naming what each expects."""
  files = [r.expected for r in map(lookup, FORMATS) if r.expected and r.file]
  held = [r.expected for r in map(lookup, FORMATS) if r.expected and not r.file]
  expected = files + ([f"a directory with {_either(held)}"] if held else [])
  return f"unknown dataset format at {path} (expected {_either(expected)})"


def _either(phrases):
  """'a, b or c' of a list of phrases."""
  return " or ".join(filter(None, [", ".join(phrases[:-1]), phrases[-1]]))
