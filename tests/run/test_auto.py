"""--config=auto by backend: on the CPU the choice is today's (the CPU config of the kind of
capture, as configs/auto.py documents it), on a GPU backend its configs/gpu/ counterpart; one
line names the backend and the choice. The backend is passed in (auto_config's argument), so
both branches run here on the CPU."""

import jax
import pytest

from nerf_jax.run import config_lib
from nerf_jax.run.auto import auto, transient_share, warm_up
from nerf_jax.run.auto.rules import backend, transients
from tests.helpers import load_data

# Today's CPU choice for each built-in scene at 24 px (auto's rules: an object on a background
# below large_objects.LARGE_IMAGES (100 px) -> fast.py, forward-facing -> llff.py, a
# frame-filling scene -> capture.py), and the GPU config that takes its place.
CPU_CHOICE = {"diffuse": "fast", "forward": "llff", "garden": "capture"}
GPU_CHOICE = {"diffuse": "gpu/lego", "forward": "gpu/llff", "garden": "capture"}
# What auto sets from the data (its effects) and what _decide sets as the user: not the config's.
NOT_THE_CONFIGS = {"data.background", "model.appearance_dims", "model.view_dependent",
                   "data.ndc", "data.lindisp", "train.random_background", "eval.appearance",
                   "data.contraction", "data.focus", "data.scene",
                   "data.image_size", "data.num_views", "auto", "auto_decisions", "auto_flags",
                   "auto_representation"}


def _decide(scene, backend):
  """auto's config for the built-in `scene` (24 px, 40 views) on `backend` (None: jax's)."""
  config = config_lib.load("auto")
  config.data.scene, config.data.image_size, config.data.num_views = scene, 24, 40
  train, _ = load_data(config.data)
  return auto.auto_config(config, train, backend=backend)


def _same_fields(decided, name):
  """[(field, decided value, configs/<name>.py's value)] of the fields that differ, leaving out
  what auto decides from the data (NOT_THE_CONFIGS)."""
  flat = auto._flat  # pylint: disable=protected-access
  mine, theirs = flat(decided), flat(config_lib.load(name))
  return [(k, mine[k], theirs.get(k)) for k in mine
          if k not in NOT_THE_CONFIGS and mine[k] != theirs.get(k)]


@pytest.mark.parametrize("scene", sorted(CPU_CHOICE))
def test_the_cpu_backend_keeps_todays_choice(scene, capsys):
  decided = _decide(scene, "cpu")
  assert _same_fields(decided, CPU_CHOICE[scene]) == []
  assert decided.auto_decisions[-1] == f"representation: configs/{CPU_CHOICE[scene]}.py"
  assert decided.auto_representation == CPU_CHOICE[scene]  # recorded, not read from the line
  backend_lines = [l for l in capsys.readouterr().out.splitlines() if "backend" in l]
  assert backend_lines == [f"auto: backend cpu: configs/{CPU_CHOICE[scene]}.py, the configs "
                           "measured on a CPU (a GPU backend takes configs/gpu/)"]


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="the default backend is not a CPU")
def test_the_default_backend_here_is_the_cpus_branch():
  assert _decide("diffuse", None).to_json() == _decide("diffuse", "cpu").to_json()


@pytest.mark.parametrize("scene", sorted(GPU_CHOICE))
def test_a_gpu_backend_picks_the_gpu_configs(scene, capsys):
  decided = _decide(scene, "gpu")
  assert _same_fields(decided, GPU_CHOICE[scene]) == []
  assert decided.auto_representation == GPU_CHOICE[scene]
  assert decided.auto_decisions[-1] == f"representation: configs/{GPU_CHOICE[scene]}.py"
  out = capsys.readouterr().out.splitlines()
  why = (f"in place of the CPU's configs/{CPU_CHOICE[scene]}.py" if GPU_CHOICE[scene] !=
         CPU_CHOICE[scene] else "as on a CPU")  # capture.py beat gpu/capture on an H200
  line = [l for l in out if "backend" in l]
  assert len(line) == 1 and line[0].startswith(f"auto: backend gpu: configs/{GPU_CHOICE[scene]}.py")
  assert why in line[0] and "docs/gpu.md" in line[0]
  # The effects decided from the data are the CPU branch's.
  cpu = _decide(scene, "cpu")
  assert (decided.data.ndc, decided.data.background, decided.train.random_background) == (
      cpu.data.ndc, cpu.data.background, cpu.train.random_background)


def test_every_cpu_choice_has_a_gpu_config():
  assert set(backend.GPU_CONFIGS) == {"fast", "detail", "llff", "capture"}
  for name in backend.GPU_CONFIGS.values():  # each loads; those of configs/gpu/ size their renders
    assert config_lib.load(name).render.chunk == 0 or not name.startswith("gpu/")
  assert backend.GPU_CONFIGS["capture"] == "capture"  # gpu/capture lost on fox (docs/gpu.md)


@pytest.mark.parametrize("side,effects", [
    (100, {"loss.robust.weight": 1.0}),  # the switch alone: patches of train.patch_size follow
    (12, {"loss.robust.weight": 1.0, "train.patch_size": 12}),  # a patch lies in one photo
])
def test_transients_set_the_robust_switch_alone(monkeypatch, side, effects):
  monkeypatch.setattr(warm_up, "photos_and_renders", lambda dataset: (None, None))
  monkeypatch.setattr(transient_share, "transient_share", lambda photos, renders: (0.05, None))
  dataset = type("Photos", (), {"height": side, "width": side + 4})()
  decided, line = transients.transient_effects(dataset, True, 16)
  assert decided == effects
  assert line.startswith(f"transients left out: RobustNeRF's trimmed loss on {min(side, 16)} x")
  assert transients.transient_effects(dataset, False, 16)[0] == {}

