"""The settings the entry layer reads itself (run/): the run's seed and auto's record, the
training loop, the renders after training and the live viewer. Each setting is declared here
once, with its default and comment; run/schema.py builds its section from these (nothing below
run/ reads them; how rays see the scene is cameras/scene_settings.SceneSettings).
"""

import dataclasses
from typing import Tuple


@dataclasses.dataclass(frozen=True)
class RunSettings:
  """config's top-level fields of the run."""
  seed: int = 0  # PRNG seed for initialisation, ray batches and jitter
  auto: bool = False  # decide the effects and the representation from the data (configs/auto.py)
  auto_decisions: Tuple[str, ...] = ()  # what auto decided and why, one line each (filled by auto)
  auto_flags: Tuple[str, ...] = ()  # fields set on the command line (filled by nerf-train): auto keeps them
  auto_by_steps: Tuple[str, ...] = ()  # effects auto turned on that pay only from auto.MIN_STEPS steps: off below (filled by auto)
  auto_representation: str = ""  # the config auto chose ('fast', 'gpu/lego', ...; filled by auto)


@dataclasses.dataclass(frozen=True)
class LoopSettings:
  """config.train's fields of the training loop: its budget, records and checkpoints."""
  max_steps: int = 0  # step budget (0 = fitted to max_seconds if set, else default_steps)
  max_seconds: float = 0.0  # wall-clock budget in seconds; alone, the run lasts exactly this long
  default_steps: int = 2500  # step budget when neither max_steps nor max_seconds is set
  sample_budget: int = 0  # occupancy: samples a step queries (valid ones, compacted); 0 = all
  log_every: int = 100  # steps between progress lines and metrics.jsonl records
  eval_every: int = 0  # steps between test-view evaluations (0 = only at the end)
  eval_views: int = 2  # test views rendered for periodic evaluations (the final one uses all)
  checkpoint_every: int = 500  # steps between checkpoints
  keep_checkpoints: int = 2  # checkpoints kept in the workdir
  data_parallel: bool = True  # split each batch over all devices (no-op on one device)
  tensorboard: bool = True  # write TensorBoard events into <workdir>/tb
  deterministic: bool = False  # repeatable GPU runs: XLA's deterministic ops (CPUs repeat anyway)


@dataclasses.dataclass(frozen=True)
class OutputSettings:
  """config.render's fields of what is rendered after training (the rest: how, ImageSettings)."""
  video_frames: int = 60  # frames in the 360° orbit video (0: no video after training)
  video_path: str = "auto"  # 'orbit' (NDC: spiral), 'trajectory' (the capture's); auto: by data
  fps: int = 30  # video frame rate
  orbit_phi: float = -30.0  # orbit elevation in degrees
  orbit_radius: float = 4.0  # orbit distance from the origin
  after_training: bool = True  # train.py renders test views and the video when done


@dataclasses.dataclass(frozen=True)
class ViewerSettings:
  """config.viewer: the live viewer while training (viewer/training.py)."""
  enabled: bool = False  # serve the live viewer (viser) while training: pip install -e ".[viewer]"
  port: int = 7007  # port of the live viewer's page (http://localhost:PORT)
