"""The benchmark's sweeps, as data, and how a command's `Request` becomes the configs it runs.

A sweep is a list of `Entry`s: a label, a dict of dotted config overrides and the config they
apply to (a name under configs/). `SCENES` says which scenes a sweep runs on by default. A run's
config is: the entry's base config (the command's --config for entries based on 'default'), the
entry's overrides, the scene, the command's --config.FIELD overrides, then the budget.
"""

import dataclasses
import json
import os
from typing import NamedTuple

import ml_collections

from nerf_jax.data import scenes
from nerf_jax.run import config_lib
from nerf_jax.run import train_lib


class Entry(NamedTuple):
  label: str  # short name in tables and plots
  overrides: dict = {}  # dotted config field -> value, e.g. {'model.width': 128}
  base: str = "default"  # config name under configs/ the overrides apply to


_NO_SKIP = {"model.skip_layers": ()}  # a 4-layer MLP has no layer 4 to skip after
_VIEW = {"model.view_dependent": True}  # the view branch (glossy parts)
# Held-out photos with their own looks, scored on right halves, codes fitted on left halves.
_OWN_LOOKS = {"data.held_out_looks": "own", "eval.appearance": "left_half"}

SWEEPS = {
    "quick": [
        Entry("default"),
        Entry("samples=32", {"num_samples": 32}),
        Entry("64x4", {"model.depth": 4, **_NO_SKIP}),
    ],
    "samples": [Entry(f"samples={n}", {"num_samples": n}) for n in (16, 32, 64, 128)],
    "freqs": [Entry(f"freqs={n}", {"pos_encode_dims": n}) for n in (0, 4, 6, 10, 16)],
    "width": [
        Entry("64x4", {"model.width": 64, "model.depth": 4, **_NO_SKIP}),
        Entry("64x8", {"model.width": 64, "model.depth": 8}),
        Entry("128x8", {"model.width": 128, "model.depth": 8}),
        Entry("256x8", {"model.width": 256, "model.depth": 8}),
    ],
    "configs": [Entry("default"), Entry("keras_seed", base="keras_seed"),
                Entry("tiny_nerf", base="tiny_nerf"), Entry("fast", base="fast")],
    "effects": [
        Entry("baseline"),
        Entry("+hierarchical", {"num_fine_samples": 64}),
        Entry("+view_dependent", {"model.view_dependent": True}),
        Entry("+white_bg", {"data.background": "white"}),
    ],
    "precision": [
        Entry("f32 8x64", {"model.dtype": "float32"}),
        Entry("bf16 8x64", {"model.dtype": "bfloat16"}),
        Entry("f32 8x256", {"model.dtype": "float32", "model.width": 256}),
        Entry("bf16 8x256", {"model.dtype": "bfloat16", "model.width": 256}),
    ],
    # Empty-space skipping on the fast grid model: the same samples placed only where it is full.
    "occupancy": [
        Entry("fast", base="fast"),
        Entry("fast+occupancy", {"occupancy.enabled": True}, base="fast"),
        Entry("fast+occupancy samples=32", {"occupancy.enabled": True, "num_samples": 32},
              base="fast"),
    ],
    # The field in cache-sized chunks of rays, recomputed in the backward pass (train.remat_chunk).
    "remat": [Entry("default"), Entry("remat_chunk=128", {"train.remat_chunk": 128}),
              Entry("256x8", {"model.width": 256}),
              Entry("256x8 remat_chunk=32", {"model.width": 256, "train.remat_chunk": 32})],
    # Candidates for the default MLP's early convergence (the 60 s point against keras_seed).
    "default_tuning": [
        Entry("default"),
        Entry("remat", {"train.remat_chunk": 128}),
        Entry("samples=32 remat", {"num_samples": 32, "train.remat_chunk": 128}),
        Entry("samples=16 remat", {"num_samples": 16, "train.remat_chunk": 128}),
        Entry("samples=32 remat rays=512", {"num_samples": 32, "train.remat_chunk": 128,
                                            "train.batch_rays": 512}),
        Entry("samples=32 remat lr=5e-3", {"num_samples": 32, "train.remat_chunk": 128,
                                           "train.lr": 5e-3}),
        Entry("samples=32 remat box", {"num_samples": 32, "train.remat_chunk": 128,
                                       "data.scene_bound": 1.5}),
        Entry("samples=32 remat rays=512 lr=5e-3", {"num_samples": 32, "train.remat_chunk": 128,
                                                    "train.batch_rays": 512, "train.lr": 5e-3}),
        Entry("samples=64 remat rays=512 lr=5e-3", {"train.remat_chunk": 128,
                                                    "train.batch_rays": 512, "train.lr": 5e-3}),
        Entry("samples=32 remat rays=256 lr=5e-3", {"num_samples": 32, "train.remat_chunk": 128,
                                                    "train.batch_rays": 256, "train.lr": 5e-3}),
        Entry("samples=48 remat rays=512 lr=5e-3", {"num_samples": 48, "train.remat_chunk": 128,
                                                    "train.batch_rays": 512, "train.lr": 5e-3}),
    ],
    # Fine detail at 400 px (scene `detail`, --image_size=400): the encodings, and what keeps
    # empty space empty, with the view branch the glossy spheres need.
    "detail": [
        Entry("mlp", {**_VIEW, "data.scene_bound": 1.5}),
        Entry("grid", _VIEW, base="fast"),  # trains on random backgrounds (fast.py's default)
        Entry("grid fixed-bg", {**_VIEW, "train.random_background": False}, base="fast"),
        # 0.012 of the normalised ray distance: 0.003 in world units over `detail`'s [2, 6]
        Entry("grid distortion", {**_VIEW, "loss.distortion.weight": 0.012}, base="fast"),
        Entry("grid occupancy", {**_VIEW, "occupancy.enabled": True}, base="fast"),
        # configs/detail.py: occupancy 64^3, 32 samples x 4096 rays, lr 2e-2 (chosen on `detail`)
        Entry("detail", base="detail"),
        Entry("grid 256", {**_VIEW, "model.grid.resolutions": (64, 128, 256),
                           "model.grid.features": 2}, base="fast"),
        Entry("hash", {**_VIEW, "model.hash.gather_dtype": "float16"}, base="hash"),
        Entry("hash occupancy", {**_VIEW, "model.hash.gather_dtype": "float16",
                                 "occupancy.enabled": True}, base="hash"),
    ],
    # Quality per CPU-second (issue 24): the configs the README recommends and their challengers,
    # each probed at 1, 2, 5 and 10 minutes (--budget_seconds=600 --eval_times=60,120,300,600)
    # on the built-in `detail` and on public NeRF-synthetic and LLFF folders (--scenes=PATH).
    "frontier": [
        # density from one-channel levels, activated after interpolation; colour only for the
        # quarter of the batch's samples with the largest weights
        Entry("detail", base="detail"),
        # the challenger it replaced: density from the MLP's first output, colour for every sample
        Entry("detail MLP density", {"model.grid.density_resolutions": (),
                                     "model.density_activation": "softplus",
                                     "model.colour_fraction": 0.0}, base="detail"),
    ],
    # The same for forward-facing captures (LLFF folders: --scenes=PATH --config.data.factor=8):
    # configs/llff.py's grids in NDC against the NDC MLP of configs/scenes/forward.py.
    "frontier_llff": [
        Entry("llff", base="llff"),
        Entry("mlp (scenes/forward.py)", base="scenes/forward"),
    ],
    # Unbounded scenes (scene `garden`, and one that does not call for it): a fixed box, the box
    # found from the data, and the rest of space contracted beyond it (+ occupancy placement).
    "contraction": [
        Entry("box 1.5 (fast)", base="fast"),
        Entry("auto box (capture)", base="capture"),
        Entry("contracted", {"data.contraction": "linf", "num_samples": 32,
                             "occupancy.enabled": True, "occupancy.resolution": 64,
                             "occupancy.probes": 1, "train.batch_rays": 4096,
                             "train.lr": 2e-2}, base="capture"),
    ],
    # A photographer's effects (scenes `exposure`, `perturbed`, and `diffuse`, which calls for
    # neither): per-photo appearance codes and camera pose refinement (appearance_and_poses.md).
    # The "own looks" pair: _OWN_LOOKS (NeRF-W's protocol for photos with looks of their own).
    "photos": [
        Entry("fast", base="fast"),
        Entry("appearance codes", {"model.appearance_dims": 8}, base="fast"),
        Entry("pose refinement", {"train.pose_refinement": True}, base="fast"),
        Entry("fast, own looks", _OWN_LOOKS, base="fast"),
        Entry("appearance codes, own looks", {**_OWN_LOOKS, "model.appearance_dims": 8},
              base="fast"),
    ],
    # Step time against the work per step (rays x samples); run with --steps (equal steps).
    "scaling": [Entry(f"rays={n}", {"train.batch_rays": n}) for n in (128, 512, 2048, 8192, 32768)]
    + [Entry(f"rays=2048 samples={s}", {"train.batch_rays": 2048, "num_samples": s})
       for s in (16, 256)],
}

# Scenes a sweep runs on unless --scenes says otherwise; the effects need scenes that call for
# them (glossy: view dependence, fog: a soft medium, white: the background) and one that doesn't.
SCENES = {"effects": ("diffuse", "glossy", "fog", "white"), "occupancy": ("diffuse", "glossy"),
          "detail": ("detail",), "frontier": ("detail",), "frontier_llff": ("forward",), "contraction": ("garden", "diffuse"),
          "photos": ("exposure", "perturbed", "diffuse")}
DEFAULT_SCENES = ("diffuse",)
# Sweeps 'all' leaves out: the small one, and the long ones at 400 px.
_ON_REQUEST = ("quick", "default_tuning", "detail", "frontier", "frontier_llff")


# Fields the bench sets itself: an override would mislabel or unbudget the runs.
OWN_FIELDS = {"data.path": "--scenes", "data.scene": "--scenes",
              "train.max_steps": "--steps or --budget_seconds",
              "train.max_seconds": "--budget_seconds or --steps"}


@dataclasses.dataclass
class Request:
  """The runs a bench command asks for (each field is the flag of the same name)."""
  sweep: str = "all"  # comma list of sweep names, or 'all'
  only: tuple = ()  # configuration labels to keep (empty: all)
  scenes: tuple = ()  # built-in scene names or dataset paths (empty: each sweep's own)
  base: str = "default"  # --config: the config replacing configs/default.py as the entries' base
  overrides: dict = dataclasses.field(default_factory=dict)  # --config.FIELD: typed values
  image_size: int = None  # built-in scenes: image side (None: the config's)
  steps: int = 0  # equal-steps mode when > 0
  budget_seconds: float = 120.0  # else equal wall clock, compilation included
  keep_schedule: bool = False  # budget mode: the config's max_steps and schedule, not fitted


def sweep_names(spec):
  """Sweep names from a comma list; 'all' = every sweep but those run only on request."""
  names = [n.strip() for n in spec.split(",") if n.strip()]
  if names == ["all"]:
    return [n for n in SWEEPS if n not in _ON_REQUEST]
  unknown = [n for n in names if n not in SWEEPS]
  if unknown:
    raise ValueError(f"--sweep: unknown sweep(s) {', '.join(unknown)} "
                     f"(valid: all, {', '.join(SWEEPS)})")
  return names


def scene_overrides(scene, image_size=None):
  """Data overrides for a built-in scene name or a dataset path."""
  if scene in scenes.SCENES:
    out = {"data.path": "", "data.scene": scene}
    return out if image_size is None else {**out, "data.image_size": image_size}
  if os.path.exists(scene):
    return {"data.path": scene}
  raise ValueError(f"--scenes: {scene!r} is neither a built-in scene "
                   f"({', '.join(scenes.SCENES)}) nor an existing dataset path")


def scene_label(scene):
  return scene if scene in scenes.SCENES else os.path.basename(scene.rstrip("/"))


def make_config(entry, scene, overrides=None, base="default", image_size=None):
  """The ConfigDict of one run: base config, entry overrides, scene, then `overrides`.

  base: a config name or path (config_lib.resolve) replacing the entry's base when that is
  'default' (e.g. 'debug' for tests).
  """
  name = base if entry.base == "default" else entry.base
  config = config_lib.load(name)
  flat = {**entry.overrides, **scene_overrides(scene, image_size), **(overrides or {})}
  config.lock()  # a misspelt field is an error, not a new field
  try:
    config.update_from_flattened_dict(flat)
  except (KeyError, AttributeError, TypeError) as e:
    raise ValueError(f"config {name}: cannot apply overrides {flat}: {e}") from None
  return config


fit_schedule = train_lib.fit_schedule  # stretch the schedule to a number of steps


def as_config(config_json):
  """A ConfigDict back from `config.to_json()`."""
  return ml_collections.ConfigDict(json.loads(config_json))


def plan(request):
  """[(sweep, Entry, scene, ConfigDict)] of every run `request` asks for."""
  for field in request.overrides:
    if field in OWN_FIELDS:
      raise ValueError(f"--config.{field}: the bench sets it; use {OWN_FIELDS[field]}")
  only = set(request.only)
  runs = []
  for sweep in sweep_names(request.sweep):
    for scene in request.scenes or SCENES.get(sweep, DEFAULT_SCENES):
      for entry in SWEEPS[sweep]:
        if only and entry.label not in only:
          continue
        config = make_config(entry, scene, request.overrides, request.base, request.image_size)
        _set_budget(config, request)
        runs.append((sweep, entry, scene, config))
  if not runs:
    raise ValueError(f"nothing to run: --only={','.join(request.only)} matches no label of "
                     f"--sweep={request.sweep}")
  return runs


def _set_budget(config, request):
  """Equal-steps mode (--steps) or equal wall-clock mode (--budget_seconds)."""
  if request.steps:
    fit_schedule(config.train, request.steps)
    config.train.max_seconds = 0.0
  else:
    config.train.max_seconds = float(request.budget_seconds)  # the run may fit max_steps


def mode(request):
  """The budget of every run: equal steps or equal wall clock (JSON-able)."""
  if request.steps:
    return {"kind": "steps", "steps": request.steps}
  return {"kind": "budget", "budget_seconds": float(request.budget_seconds),
          "schedule": "config" if request.keep_schedule else "fitted"}
