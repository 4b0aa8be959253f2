"""Let the capture decide: the loader characterises the training views
(nerf_jax/run/characterise.py) and switches on the effects they call for, one printed line per
decision with its reason, all recorded in config.json (auto_decisions): opacity with empty pixels ->
an object on a background (configs/fast.py: a box, random backgrounds; configs/detail.py from 400
px); cameras all facing one way within 30° -> forward-facing (NDC rays); otherwise the content fills
the photos -> configs/capture.py (the box from the data; over a quarter of the training rays leaving
that box -> the space beyond it contracted, and cameras that all look at one point -> the world
centred there, docs/photo_collections.md); photos of nearly the same view differing in colour ->
per-photo appearance codes, held-out photos scored the NeRF-W way (eval.appearance='left_half').
A flag you set wins over auto's decision (one line says so).

  python train.py --config=auto --config.data.path=DIR --config.data.factor=4
"""

from nerf_jax.configs import capture


def get_config():
  config = capture.get_config()
  config.auto = True  # decided when the data is loaded (auto.auto_config)
  return config
