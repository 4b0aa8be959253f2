"""Let the capture decide (docs/auto.md: every rule, its threshold and how to override it): the
photos' size (data.factor), the representation (configs/fast.py, detail.py, llff.py or
capture.py, their configs/gpu/ counterparts on a GPU) and the effects the training views call
for, one printed line per decision with its reason, all recorded in config.json
(auto_decisions). A flag you give wins over auto's decision (one line says so).

  python train.py --config=auto --config.data.path=DIR
"""

from nerf_jax.configs import capture


def get_config():
  config = capture.get_config()
  config.auto = True  # decided when the data is loaded (auto.auto_config)
  return config
