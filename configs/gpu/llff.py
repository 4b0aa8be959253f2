"""Forward-facing LLFF photos (fern and its kind) on one GPU: configs/llff.py's dense grids in
NDC with finer levels (to 512 points), cells longer in depth than across (DVGO's NDC grids) and
the total variation that TensoRF and DVGO use on LLFF, at TensoRF's and DVGO's 4096 rays per
step (2^18 samples).

Measured on one H200 (docs/gpu.md, "Measured on one H200"): 23.85 dB on fern in 81 s, with a
peak of 24.29 dB at 15 s: the fine grids overfit the 17 photos as it trains on (the goal is
25.5 dB in 120 s; llff.py made 23.34 dB in 60 s there). docs/gpu.md, section "GPU
configurations", gives the source of each value. On a CPU they build and train
(tests/topics/test_gpu_configs.py, shrunk) but are far too large to pay: there, use configs/llff.py.

  python train.py --config=gpu/llff --config.data.path=DIR --config.data.factor=8
"""

from nerf_jax.configs import llff


def get_config():
  config = llff.get_config()
  config.model.grid.resolutions = (64, 128, 256, 512)  # finer levels: 512 across the NDC box
  config.model.grid.features = 4  # features per lattice point (llff.py's)
  config.model.grid_cell_aspect = (1.0, 1.0, 4.0)  # cells 4x longer in depth (DVGO's NDC grid)
  config.loss.total_variation.weight = 1e-2  # the tables' total variation, TensoRF's LLFF scale
  config.num_samples = 64  # samples per ray over NDC's [0, 1] (llff.py's)
  config.train.batch_rays = 4096  # TensoRF's and DVGO's rays per step on LLFF: 2^18 samples
  config.train.lr = 1e-2  # fast.py's and instant-ngp's Adam learning rate
  config.train.adam_b2 = 0.99  # instant-ngp's beta2 (llff.py's, measured on fern)
  config.train.adam_eps = 1e-15  # instant-ngp's epsilon: rarely-hit table rows still move at lr
  config.train.max_seconds = 120.0  # the fern goal is at two minutes
  config.render.chunk = 0  # rays per render call sized from the device's memory
  return config
