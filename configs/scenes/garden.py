"""`garden`: an unbounded scene — objects in the middle, trees, a shed and a boulder 5.5-7.5 away,
walls at 16 and a sky closing the room; every ray ends on a surface (opacity 1), depths from 1.9
to 26.5, cameras low (2°-20°) at radius 4.

A placeholder until contraction lands in the renderer: this is configs/fast.py unchanged, whose
scene box (+-1.5) holds only the middle, so the surroundings cannot be learnt yet. The pieces
for the whole scene are in nerf_jax/contraction.py (contract/uncontract, the inner region's exit)
and nerf_jax/sampling.py (`stratified_unbounded`: linear in t inside, linear in disparity out to
far = inf); the sampler work wires them in and sets this config's switches.

  python train.py --config=configs/scenes/garden.py --workdir=runs/garden
  python -m nerf_jax.data.export --scene=garden --format=blender --out=/tmp/garden
"""

from nerf_jax.configs import fast


def get_config():
  config = fast.get_config()
  config.data.scene = "garden"  # the built-in unbounded scene
  return config
