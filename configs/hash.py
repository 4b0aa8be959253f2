"""configs/fast.py with a multiresolution hash grid (instant-ngp) instead of the dense grids: 16
levels from 16 to 2048 lattice points per side, for detail at 400-800 px (the densest dense grid,
128^3, blurs textures there). First values, not yet tuned by training: the table size trades
collisions (detail) for step time, see docs/hashgrid.md for measured step times.

  python train.py --config=configs/hash.py --workdir=runs/hash
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.model.encoding = "hash"  # multiresolution hash grid (fields/encodings/hash.py)
  config.model.hash.levels = 16  # instant-ngp's 16 levels
  config.model.hash.log2_size = 17  # 2^17 rows per hashed level: 3.4M table parameters
  config.model.hash.features = 2  # 2 features per row: 32 inputs to the MLP
  config.model.hash.base_resolution = 16  # coarsest level: 16^3, indexed densely
  config.model.hash.max_resolution = 2048  # finest level: cells of 3/2047 ≈ 0.0015 units
  config.model.hash.gather_dtype = "float32"  # float16 ~25% faster (docs/hashgrid.md), untried
  return config
