"""Shared test helpers: one-line data errors and a minimal Blender folder."""

import json

import imageio.v3 as iio
import numpy as np
import pytest

from nerf_jax.data import DataError


def assert_data_error(match, fn, *args, **kw):
  """fn(*args, **kw) raises a one-line DataError containing every string of `match`."""
  with pytest.raises(DataError) as info:
    fn(*args, **kw)
  message = str(info.value)
  assert "\n" not in message
  for part in match:
    assert part in message, (part, message)


def blender_folder(tmp_path, meta=None, image=None, text=None):
  """A one-frame Blender folder; `meta` overrides keys of the JSON (None deletes), `text`
  replaces it; `image` uint8 [H, W, C] replaces the 4×4 transparent frame."""
  iio.imwrite(tmp_path / "r_0.png", np.zeros((4, 4, 4), np.uint8) if image is None else image)
  content = {"camera_angle_x": 0.69, "frames": [{"file_path": "./r_0",
                                                 "transform_matrix": np.eye(4).tolist()}]}
  content.update(meta or {})
  content = {k: v for k, v in content.items() if v is not None}
  (tmp_path / "transforms_train.json").write_text(text or json.dumps(content))
  return str(tmp_path)
