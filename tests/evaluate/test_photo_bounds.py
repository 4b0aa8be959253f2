"""data.photo_bounds at evaluation: each held-out view is rendered between its own near and far
(Dataset.bounds), as its training photos are sampled; without it, between the shared ones."""

import dataclasses

import numpy as np
import pytest

from nerf_jax.render import image_renderer
from nerf_jax.run import builders, experiment
from tests.helpers import small_config


def _recording(seen):
  """A stand-in image renderer that records each view's rays' near and far (no NeRF compiled)."""
  def draw(rays, background=None):
    seen.append((np.asarray(rays.near), np.asarray(rays.far)))
    shape = rays.shape
    return {"rgb": np.full(shape + (3,), 0.5, np.float32), "depth": np.zeros(shape, np.float32),
            "acc": np.zeros(shape, np.float32)}
  return lambda *a: lambda params: draw


@pytest.mark.parametrize("photo_bounds", [True, False])
def test_each_held_out_view_is_rendered_within_its_own_bounds(monkeypatch, photo_bounds):
  seen = []
  monkeypatch.setattr(image_renderer, "make_image_renderer", _recording(seen))
  exp = experiment.setup(small_config({"data.image_size": 8}))
  bounds = np.stack([np.linspace(2.0, 2.5, len(exp.test_ds)),
                     np.linspace(4.0, 5.5, len(exp.test_ds))], -1).astype(np.float32)
  exp = dataclasses.replace(exp, test_ds=dataclasses.replace(exp.test_ds, bounds=bounds))
  exp.config.data.photo_bounds = photo_bounds
  builders.make_evaluator(exp)({"params": {}})
  assert len(seen) == len(bounds) >= 2
  for k, (near, far) in enumerate(seen):
    want = bounds[k] if photo_bounds else (exp.near, exp.far)
    np.testing.assert_array_equal(near, np.float32(want[0]))
    np.testing.assert_array_equal(far, np.float32(want[1]))


def test_views_without_bounds_are_refused():
  exp = experiment.setup(small_config({"data.image_size": 8}))
  exp.config.data.photo_bounds = True
  with pytest.raises(ValueError, match="data.photo_bounds"):
    builders.make_evaluator(dataclasses.replace(
        exp, test_ds=dataclasses.replace(exp.test_ds, bounds=None)))
