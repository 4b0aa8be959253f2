"""configs/gpu/*.py: each builds the network its docstring and comments name (checked at full
size on shapes alone, against the sizes computed here from instant-ngp's definitions), and trains
a few steps on the CPU when shrunk to a tiny size."""

import jax
import numpy as np
import pytest

from nerf_jax.fields.encodings.grid import DenseGrid
from nerf_jax.fields.encodings.hash import HashGrid
from nerf_jax.fields.networks.lattice import LatticeHead
from nerf_jax.run import builders, config_lib, train_lib
from nerf_jax.train.losses import total_variation
from tests.helpers import small_config

GPU_CONFIGS = ("gpu/lego", "gpu/capture", "gpu/llff")
SAMPLES_PER_STEP = 2 ** 18  # instant-ngp's and nerfacc's target samples per step


def _hash_rows(levels, base, finest, log2_size):
  """Rows of instant-ngp's table, from its definition: level l has R_l = round(base · b^l)
  points per side, b = (finest / base)^(1 / (levels - 1)), and min(R_l^3, 2^log2_size) rows."""
  growth = (finest / base) ** (1.0 / (levels - 1))
  return sum(min(round(base * growth ** l) ** 3, 2 ** log2_size) for l in range(levels))


def _param_shapes(config):
  """{name: shape} of the coarse network's parameters, from shapes alone (nothing allocated)."""
  rr = builders.make_ray_renderer(config)
  shapes = jax.eval_shape(rr.init, jax.random.PRNGKey(0))["params"]["coarse"]
  return rr, jax.tree_util.tree_map(lambda a: a.shape, shapes)


def test_lego_is_instant_ngps_field_with_its_sample_budget():
  config = config_lib.load("gpu/lego")
  rr, shapes = _param_shapes(config)
  assert isinstance(rr.field.network, LatticeHead)
  assert isinstance(rr.field.network.encoding, HashGrid)
  assert shapes["hash_table"] == (_hash_rows(16, 16, 2048, 19), 2)  # 6,080,903 rows
  assert shapes["hidden"]["kernel"] == (16 * 2, 64)  # 16 levels x 2 features -> 64 wide
  assert shapes["view"]["kernel"] == (64 + 27, 64)  # + 4 frequency bands of the direction
  assert shapes["view_1"]["kernel"] == (64, 64)  # instant-ngp's two-layer colour network
  assert "view_2" not in shapes
  assert config.occupancy.enabled and config.occupancy.resolution == 128
  assert config.train.sample_budget == SAMPLES_PER_STEP
  assert (config.train.lr, config.train.adam_b2) == (1e-2, 0.99)
  assert config.loss.colour.huber_delta == 0.1  # instant-ngp's loss: won on a CPU at equal steps
  assert config.train.ema_decay == 0.0  # lost there: scores use the last weights
  assert config.render.chunk == 0  # sized from the device's memory


def test_capture_contracts_space_with_a_larger_field():
  config = config_lib.load("gpu/capture")
  rr, shapes = _param_shapes(config)
  assert isinstance(rr.field.network, LatticeHead)
  assert isinstance(rr.field.network.encoding, HashGrid)
  assert config.data.contraction == "linf" and config.data.scene_bound == -1
  assert shapes["hash_table"] == (_hash_rows(16, 16, 4096, 21), 2)  # 22,548,944 rows
  assert shapes["hash_table"][0] > 3 * _hash_rows(16, 16, 2048, 19)  # larger than lego's
  assert shapes["hidden"]["kernel"] == (32, 128)
  assert shapes["view"]["kernel"] == (128 + 27, 128)  # + capture.py's 4 direction bands
  assert shapes["view_1"]["kernel"] == (128, 128)  # nerfacto's two colour layers
  assert config.occupancy.enabled and config.train.sample_budget == SAMPLES_PER_STEP
  assert config.loss.distortion.weight > 0  # capture.py's measured effect, kept


def test_llff_has_finer_levels_and_total_variation_in_ndc():
  config = config_lib.load("gpu/llff")
  rr, shapes = _param_shapes(config)
  assert isinstance(rr.field.network.encoding, DenseGrid) and config.data.ndc
  # Before the NDC box is found (from_data.with_ndc_box) the grids cover the cube: the finest
  # level has 512 points across and 512 / 4 (+ 1) in depth, its cells 4x as long.
  assert shapes["grid_512"] == (512, 512, 129, 4)
  assert max(config.model.grid.resolutions) == 4 * max(config_lib.load("llff").model.grid
                                                       .resolutions)
  terms = builders.loss_terms(config, rr)
  assert [t.weight for t in terms if isinstance(t, total_variation.TotalVariation)] == [1e-2]
  assert config.train.batch_rays * config.num_samples == SAMPLES_PER_STEP


# Each config shrunk to seconds on 2 cores: a small built-in scene of its kind, a tiny field.
TINY = {"data.path": "", "data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5,
        "train.max_steps": 3, "train.max_seconds": 0.0, "train.batch_rays": 128,
        "train.log_every": 3, "train.eval_every": 0, "train.checkpoint_every": 3,
        "train.tensorboard": False, "render.video_frames": 0}
TINY_HASH = {"model.hash.levels": 4, "model.hash.log2_size": 10, "model.hash.max_resolution": 64,
             "occupancy.resolution": 16, "num_samples": 8, "train.sample_budget": 512,
             "render.num_samples": 0}
SHRUNK = {"gpu/lego": {"data.scene": "diffuse", **TINY_HASH},
          "gpu/capture": {"data.scene": "garden", **TINY_HASH},
          "gpu/llff": {"data.scene": "forward", "model.grid.resolutions": (8, 16),
                       "num_samples": 16}}


@pytest.mark.slow
@pytest.mark.parametrize("name", GPU_CONFIGS)
def test_each_gpu_config_trains_a_few_steps_when_shrunk(name, tmp_path):
  config = small_config({**TINY, **SHRUNK[name]}, base=name)
  result = train_lib.train_and_evaluate(config, str(tmp_path / "run"))
  assert result["steps"] == 3 and np.isfinite(result["psnr"])
