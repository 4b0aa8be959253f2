"""What a run is made of, built once for every entry point (training, rendering, benchmarks,
the viewer, tests): the config, the model, the optimiser, the datasets and the ray bounds; the
train state and its checkpoint signature; and restoring all of it from a workdir.
"""

import collections
import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
import optax

from nerf_jax.backend import precision
from nerf_jax.fields import model
from nerf_jax.run import auto, config_lib
from nerf_jax.samplers import occupancy, visual_hull
from nerf_jax.render import background
from nerf_jax.train import checkpoints, losses, train_batches, train_step
from nerf_jax.data import loaders
from nerf_jax.data.dataset import Dataset
from nerf_jax.fields.field import Field
from nerf_jax.render.image_renderer import ImageSettings
from nerf_jax.cameras.rays import camera_rays, pixel_rays
from nerf_jax.render.renderer import RayRenderer
from nerf_jax.train.state import TrainState  # noqa: F401  (re-exported)
from nerf_jax.samplers.sampler import Sampler


class TrainingError(RuntimeError):
  """Training cannot go on (non-finite loss, bad config); the message says why and what to do."""


@dataclasses.dataclass
class Experiment:
  """A config and what it builds. near, far: the ray bounds (z-depth; [0, 1] in NDC).
  renderer: the RayRenderer (field + sampler); image: how whole images are rendered."""
  config: ml_collections.ConfigDict
  renderer: RayRenderer
  image: ImageSettings
  tx: optax.GradientTransformation
  train_ds: Dataset
  test_ds: Dataset
  near: float
  far: float
  hull: Any = None  # float32 [R, R, R] visual hull on the occupancy grid's cells (data.visual_hull)

  def camera(self, scale=1.0):
    """(height, width, intrinsics) of the training camera with `scale` times its pixels per side
    (same field of view: focal lengths and principal point scale with the image)."""
    ds = self.train_ds
    height, width = max(1, round(ds.height * scale)), max(1, round(ds.width * scale))
    sx, sy = width / ds.width, height / ds.height
    fx, fy, cx, cy = ds.intrinsics
    return height, width, (fx * sx, fy * sy, cx * sx, cy * sy)

  @property
  def pixel_center(self):
    """Where in its pixel each ray passes: config.data.pixel_center, or the data's own (-1)."""
    return pixel_center(self.config, self.train_ds)

  def rays(self, pose, camera=None):
    """Rays [H, W] of `pose` (float32 [4, 4] camera-to-world) through `camera` (default: the
    training camera), as the config asks (pixel centres, NDC)."""
    height, width, intrinsics = camera or self.camera()
    return camera_rays(height, width, intrinsics, pose, self.near, self.far,
                       self.pixel_center, self.config.data.ndc)


def setup(config):
  """The Experiment of `config`: loads the data, builds the renderer and the optimiser."""
  config = config_lib.upgrade(config)
  make_ray_renderer(config)  # a bad model or sampler setting fails before the data loads
  train_ds, test_ds = loaders.load_dataset(config.data)
  if config.auto:
    config = auto.auto_config(config, train_ds)
  pixel_center(config, train_ds)  # a bad value fails here, naming the field
  near, far = bounds(config, train_ds)
  config = with_scene_extent(config, train_ds)
  config = with_ndc_box(config, train_ds, near, far)
  config, hull = with_visual_hull(config, train_ds)
  exp = Experiment(config, make_ray_renderer(config, len(train_ds)), image_settings(config),
                   optimizer_for(config), train_ds, test_ds, near, far, hull)
  warn_if_cut(exp)
  return exp


def with_scene_extent(config, dataset):
  """`config` with data.scene_bound = -1 (auto) resolved from the data, one line saying how:
  in an unbounded scene (data.contraction) the inner box is the subject's (Dataset.core:
  instant-ngp's unit cube, or the sparse points' box), else the cameras'; in a bounded one it
  is the data's whole box (Dataset.aabb: instant-ngp's aabb_scale or the sparse points), else
  the cameras'. The value (and the grids' box, model.grid_bound) is recorded in config.json."""
  if config.data.scene_bound != -1:
    return config
  box = dataset.core if config.data.contraction else dataset.aabb
  if box is None:
    bound, why = float(np.max(np.abs(dataset.poses[:, :3, 3]))), "the cameras' box"
  else:
    bound = float(np.max(np.abs(box)))
    why = "the subject's box (core)" if config.data.contraction else "the data's box (aabb)"
  config = ml_collections.ConfigDict(config.to_dict())
  config.data.scene_bound = round(bound, 4)
  config.model.grid_bound = round(bound, 4)  # a bounded scene's grids cover the box found
  beyond = f", contracted ({config.data.contraction}) beyond" if config.data.contraction else ""
  print(f"scene extent: box ±{bound:.3g} from {why}{beyond} (data.scene_bound)", flush=True)
  return config


NDC_MARGIN = 0.02  # share of each side added around the training rays' NDC box


def with_ndc_box(config, dataset, near, far):
  """`config` with the grid encodings' box (model.grid_box) found from the data in an NDC run
  that sets none: the box of every training ray's ends in NDC (t = 0 on the near plane and
  t = 1 at infinity), NDC_MARGIN wider on each side, so no photo's frustum is cut, and no cells
  are spent beyond them. One line says so; the box is recorded in config.json."""
  m = config.model
  if not config.data.ndc or m.encoding == "posenc" or m.grid_box:
    return config
  # A pinhole camera maps its pixel grid projectively onto any plane, so the NDC ends of its
  # rays span the quadrilateral of its corner pixels' rays.
  i = jnp.array([0.0, dataset.width - 1.0, 0.0, dataset.width - 1.0])
  j = jnp.array([0.0, 0.0, dataset.height - 1.0, dataset.height - 1.0])
  ends = []
  for pose in dataset.poses:
    rays = pixel_rays(i, j, dataset.height, dataset.width, dataset.intrinsics, pose, near, far,
                      pixel_center(config, dataset), use_ndc=True)
    ends += [np.asarray(rays.origins), np.asarray(rays.origins + rays.directions)]
  ends = np.concatenate(ends)
  low, high = ends.min(axis=0), ends.max(axis=0)
  pad = NDC_MARGIN * (high - low)
  low, high = np.maximum(low - pad, -1e3), np.minimum(high + pad, 1e3)
  config = ml_collections.ConfigDict(config.to_dict())
  config.model.grid_box = tuple(round(float(v), 4) for v in (*low, *high))
  corner = lambda c: "(" + ", ".join(f"{float(v):.3f}" for v in c) + ")"
  print(f"NDC extent: the training rays span {corner(low)} to {corner(high)}; the grids cover "
        "it (model.grid_box)", flush=True)
  return config


HULL_RESOLUTION = 64  # cells per side of the carved grid when no occupancy grid sets it


def with_visual_hull(config, dataset):
  """(config, hull): with data.visual_hull on data with opacity, the training masks are carved
  (visual_hull.py) on the occupancy grid's cells (else 64^3 cells of the grids' cube), the grid
  encodings' box (model.grid_box, recorded in config.json) becomes the hull's bounding box and
  `hull` (float32 [R, R, R]) is returned for the occupancy grid; else (config, None)."""
  if not config.data.visual_hull:
    return config, None
  if dataset.accs is None or config.data.contraction:
    why = "the data has no opacity" if dataset.accs is None else "the scene is unbounded"
    print(f"note: data.visual_hull is ignored: {why}", flush=True)
    return config, None
  occupied = config.occupancy.enabled
  bound = config.data.scene_bound if occupied else config.model.grid_bound
  resolution = config.occupancy.resolution if occupied else HULL_RESOLUTION
  hull = visual_hull.carve(dataset.accs, dataset.poses, dataset.intrinsics, bound, resolution,
                           pixel_center(config, dataset))
  box = visual_hull.bounding_box(hull, bound)
  config = ml_collections.ConfigDict(config.to_dict())
  config.model.grid_box = tuple(round(float(v), 4) for v in box.reshape(-1))
  share = float(np.mean(np.asarray(hull)))
  corner = lambda c: "(" + ", ".join(f"{float(v):.3f}" for v in c) + ")"
  print(f"visual hull: {100 * share:.1f}% of the box's cells; the grids cover "
        f"{corner(box[0])} to {corner(box[1])} (model.grid_box)", flush=True)
  return config, hull if occupied else None


CUT_SHARE = 0.25  # a run warns when more training rays than this leave the box before far


VIEWS_CHECKED, RAYS_PER_SIDE = 8, 16  # warn_if_cut looks at 16 x 16 rays of ~8 views


def warn_if_cut(exp):
  """One line when many training rays leave the scene box before their far bound: what lies
  beyond is cut from the model (a bounded box on a real capture). Data with opacity (RGBA,
  built-in scenes) says where the scene is empty, so nothing is cut there: no line."""
  sampler = exp.renderer.sampler
  if (sampler.scene_bound <= 0 or sampler.contraction or exp.config.data.ndc
      or exp.train_ds.accs is not None):
    return
  poses = exp.train_ds.poses
  views = poses[::max(1, len(poses) // VIEWS_CHECKED)]
  camera = exp.camera(RAYS_PER_SIDE / max(exp.train_ds.height, exp.train_ds.width))
  cut = [np.mean(np.asarray(sampler.bounds(rays)[1]) < 0.95 * np.asarray(rays.far))
         for rays in (exp.rays(pose, camera) for pose in views)]
  share = float(np.mean(cut))
  if share > CUT_SHARE:
    print(f"note: {100 * share:.0f}% of training rays leave the scene box "
          f"(±{sampler.scene_bound:g}) before their far bound ({exp.far:.3g}): what lies "
          "beyond is not modelled; for a garden or a street set data.contraction='linf' "
          "(docs/real_captures.md), or data.scene_bound=-1 (the box from the data)", flush=True)


ENCODINGS = ("posenc", "grid", "hash", "tensorf")


def make_field(config, num_images=1):
  """The Field of `config.model` (and the top-level encoding bands): the network of
  `model.encoding`, built from the encoding's own subsection (model.grid, model.hash) and the
  head's fields (model.tensorf for 'tensorf'). num_images: training images, the rows of the
  appearance codes' table (model.appearance_dims > 0)."""
  m = config.model
  if m.encoding not in ENCODINGS:
    raise ValueError(f"config.model.encoding must be one of {', '.join(ENCODINGS)}, got "
                     f"{m.encoding!r}")
  if m.appearance_dims < 0:
    raise ValueError(f"config.model.appearance_dims={m.appearance_dims}: use 0 (off) or the "
                     "length of each training image's appearance code (e.g. 8)")
  precision.network_precision(m.matmul_precision)  # ValueError naming the field if unknown
  head = dict(view_dependent=m.view_dependent, view_width=m.view_width, dtype=m.dtype,
              matmul_precision=m.matmul_precision)
  if m.appearance_dims:  # only then, so the networks of runs without codes stay as they were
    head.update(appearance_images=max(int(num_images), 1), appearance_dims=m.appearance_dims)
  if m.encoding == "posenc":
    network = model.NerfMLP(depth=m.depth, width=m.width, skip_layers=tuple(m.skip_layers),
                            **head)
  else:
    # In an unbounded scene the grids cover the whole contracted space, twice the inner box.
    bound = 2.0 * config.data.scene_bound if config.data.contraction else m.grid_bound
    fields = dict(m[m.encoding])
    if m.encoding == "grid" and not m.grid.density_resolutions:
      hashed = {name: fields.pop(name) for name in _HASHED_LEVELS}
      if hashed["density_hash_resolution"] or hashed["colour_hash_resolution"]:
        raise ValueError("config.model.grid.density_hash_resolution and colour_hash_resolution "
                         "add levels to the split network: they need "
                         "config.model.grid.density_resolutions")
    if m.encoding in ("hash", "tensorf"):
      grids = {"hash": model.HashNeRF, "tensorf": model.TensoRFNeRF}[m.encoding]
    elif fields.pop("density_resolutions"):  # density from a grid of its own
      grids = functools.partial(model.DensityGridNeRF,
                                density_resolutions=tuple(m.grid.density_resolutions))
      if m.density_activation == "relu":
        raise ValueError("config.model.grid.density_resolutions needs "
                         "config.model.density_activation 'softplus' or 'exp': the density "
                         "grid starts below zero, where relu has no gradient")
      if m.appearance_dims:
        raise ValueError("config.model.grid.density_resolutions does not take appearance codes "
                         "yet: set config.model.appearance_dims=0 or density_resolutions=()")
    else:
      grids = model.GridNeRF
    network = grids(**fields, bound=bound, box=tuple(m.grid_box), hidden=m.width,
                    cell_aspect=tuple(m.grid_cell_aspect), **head)
  return Field(network, config.pos_encode_dims if m.encoding == "posenc" else None,
               config.dir_encode_dims, m.view_dependent, m.density_activation, m.density_noise,
               config.data.contraction, max(config.data.scene_bound, 1e-6), m.appearance_dims)


def make_sampler(config):
  """The Sampler of `config` (samples, scene box, spacing, occupancy); ValueError naming the
  field when occupancy sampling cannot work with the rest."""
  oc = config.occupancy
  if oc.enabled:
    if config.data.scene_bound <= 0 and config.data.scene_bound != -1:
      raise ValueError("config.occupancy.enabled needs config.data.scene_bound > 0 or -1 "
                       "(auto): the grid covers that box")
    if config.num_fine_samples > 0:
      raise ValueError("config.occupancy.enabled and config.num_fine_samples > 0 cannot be "
                       "combined: the occupancy grid already places the samples; set one of "
                       "them")
    if config.data.ndc:
      raise ValueError("config.occupancy.enabled does not work with config.data.ndc")
  settings = occupancy.OccupancySettings(**{k: v for k, v in oc.items() if k != "enabled"})
  if config.data.contraction:
    if config.data.scene_bound <= 0 and config.data.scene_bound != -1:
      raise ValueError("config.data.contraction needs config.data.scene_bound > 0 or -1 "
                       "(auto): the inner region's half-size")
    if config.data.ndc or config.num_fine_samples > 0:
      raise ValueError("config.data.contraction does not work with config.data.ndc or "
                       "config.num_fine_samples > 0 yet")
  return Sampler(config.num_samples, config.data.scene_bound, config.data.lindisp,
                 settings if oc.enabled else None, config.data.contraction,
                 config.data.inner_fraction)


def make_ray_renderer(config, num_images=1):
  """The RayRenderer of `config`: its field, its sampler and the fine pass (num_images: see
  `make_field`). Its sample budget is 0 (every slot): training sets config.train.sample_budget
  (`training_renderer`)."""
  if config.train.sample_budget and not config.occupancy.enabled:
    raise ValueError("config.train.sample_budget needs config.occupancy.enabled: the budget "
                     "is spent on the samples the occupancy grid places (0 = off)")
  return RayRenderer(make_field(config, num_images), make_sampler(config),
                     config.num_fine_samples, config.model.shared_fine,
                     config.model.colour_fraction)


def training_renderer(exp):
  """exp.renderer with the config's training sample budget (renderer.RayRenderer)."""
  return dataclasses.replace(exp.renderer, sample_budget=exp.config.train.sample_budget)


def batch_settings(config):
  """train_batches.BatchSettings of `config.train`."""
  fields = (f.name for f in dataclasses.fields(train_batches.BatchSettings))
  return train_batches.BatchSettings(**{name: config.train[name] for name in fields})


def rays_per_step(config, dataset):
  """Rays in one train step of `config` on `dataset`'s images."""
  return train_batches.rays_per_step(batch_settings(config), dataset.height, dataset.width)


def step_settings(exp):
  """train_step.StepSettings of the run `exp` describes."""
  tc = exp.config.train
  return train_step.StepSettings(
      batch=batch_settings(exp.config),
      background=tuple(float(v) for v in background.parse(exp.config.data.background)),
      random_background=background.trains_on_random(tc.random_background,
                                                    exp.train_ds.accs is not None),
      planned_steps=schedule_steps(tc), remat_chunk=tc.remat_chunk,
      pose_refinement=tc.pose_refinement, pose_coarse_to_fine=tuple(tc.pose_coarse_to_fine),
      pose_ray_share=tc.pose_ray_share)


def loss_terms(config, ray_renderer):
  """The train step's loss terms (train/losses.py) of `config`, in the order they are added."""
  tc = config.train
  terms = [losses.Colour(tc.coarse_loss_weight)]
  if tc.distortion_weight > 0:
    terms.append(losses.Distortion(tc.distortion_weight, ray_renderer.sampler.unit_distance))
  if tc.pose_refinement and tc.pose_prior > 0:
    terms.append(losses.PosePrior(tc.pose_prior))
  if tc.tv_weight > 0:
    terms.append(losses.TotalVariation(tc.tv_weight))
  return terms


def make_train_step(exp, mesh=None):
  """The jitted train step of `exp` (train_step.make_train_step; mesh: see there)."""
  ray_renderer = training_renderer(exp)
  return train_step.make_train_step(
      ray_renderer, exp.tx, loss_terms(exp.config, ray_renderer), step_settings(exp),
      functools.partial(optimizer_for, exp.config), mesh)


_STEPS = collections.OrderedDict()  # the few most recent train steps, see `cached_train_step`


def cached_train_step(exp, mesh=None):
  """`make_train_step`, reused for an equal config in the same process (tests, sweeps and
  resumed runs then compile it once): the step depends on nothing else."""
  key = (exp.config.to_json(), exp.near, exp.far, mesh)
  if key not in _STEPS:
    _STEPS[key] = make_train_step(exp, mesh)
    while len(_STEPS) > 4:
      _STEPS.popitem(last=False)
  _STEPS.move_to_end(key)
  return _STEPS[key]


def image_settings(config):
  """ImageSettings of `config.render` (no marching in NDC: the skip grid is in world space);
  ValueError naming the field for a negative sample count."""
  rc = config.render
  if rc.num_samples < 0:
    raise ValueError(f"config.render.num_samples={rc.num_samples}: use 0 (training's "
                     "num_samples) or a positive count of samples per ray")
  return ImageSettings(chunk=rc.chunk, march=rc.march and not config.data.ndc,
                       march_grid=rc.march_grid, march_threshold=rc.march_threshold,
                       march_probes=rc.march_probes, march_group=rc.march_group,
                       min_transmittance=rc.min_transmittance, num_samples=rc.num_samples)


def pixel_center(config, dataset):
  """config.data.pixel_center, or with -1 the dataset's (what its images were taken through);
  ValueError naming the field for any other value outside [0, 1]."""
  value = config.data.pixel_center
  if value == -1:
    return float(dataset.pixel_center)
  if not 0.0 <= value <= 1.0:
    raise ValueError(f"config.data.pixel_center={value}: use -1 (the data's own), 0 (pixel "
                     "corners) or 0.5 (pixel centres)")
  return float(value)


def bounds(config, dataset):
  """(near, far): [0, 1] in NDC, else the config's overrides where set, else the dataset's."""
  if config.data.ndc:
    return 0.0, 1.0  # NDC rays run from the near plane (0) to infinity (1)
  return (float(config.data.near or dataset.near), float(config.data.far or dataset.far))


def schedule_steps(train_config):
  """The steps the schedule spans: max_steps if set, else default_steps."""
  return int(train_config.max_steps or train_config.default_steps)


def make_schedule(train_config, planned_steps=None):
  """count -> learning rate: linear warm-up from 0 to `lr` over `warmup_steps`, then exponential
  decay reaching `lr_final` at the planned steps and staying there (a time-budget run may take a
  few more).

  planned_steps: None for `schedule_steps(train_config)`, or an int32 [] (possibly traced: a
  time budget's fitted length, see budget.py, so one compiled step serves any length), over
  which warm-up keeps its share of the config's planned steps (as train_lib.fit_schedule).
  """
  tc = train_config
  planned, warmup = schedule_steps(tc), tc.warmup_steps
  if planned_steps is not None:
    warmup = jnp.round(tc.warmup_steps / max(planned, 1) * planned_steps)
    planned = planned_steps

  def schedule(count):
    count = jnp.asarray(count, jnp.float32)
    progress = jnp.clip((count - warmup) / jnp.maximum(planned - warmup, 1), 0.0, 1.0)
    decayed = tc.lr * (tc.lr_final / tc.lr) ** progress
    if tc.warmup_steps <= 0:
      return decayed
    return jnp.where(count < warmup, tc.lr * count / jnp.maximum(warmup, 1), decayed)
  return schedule


def optimizer_for(config, planned_steps=None):
  """`make_optimizer` for the run `config` describes (its codes, if model.appearance_dims)."""
  return make_optimizer(config.train, planned_steps, config.model.appearance_dims > 0)


def make_optimizer(train_config, planned_steps=None, with_codes=False):
  """Adam on the schedule (see `make_schedule`), with optional global-norm gradient clipping.
  With train.pose_refinement the camera corrections (params['poses']) have an Adam of their
  own, on the same schedule scaled to train.pose_lr; `with_codes` (appearance codes: every
  parameter named 'appearance'), so do the codes, scaled to train.appearance_lr (unless it is
  train.lr: one Adam, as in runs saved before train.appearance_lr existed); with
  train.network_lr, the MLP's layers (leaves 'kernel' and 'bias'), scaled to it."""
  tc = train_config
  schedule = make_schedule(tc, planned_steps)
  adam = optax.adam(schedule, b2=tc.adam_b2)
  if tc.grad_clip > 0:
    adam = optax.chain(optax.clip_by_global_norm(tc.grad_clip), adam)
  scaled = lambda lr: optax.adam(lambda count: lr / tc.lr * schedule(count), b2=tc.adam_b2)
  groups = {"field": adam}
  if tc.pose_refinement:
    groups["poses"] = scaled(tc.pose_lr)
  if with_codes and tc.appearance_lr != tc.lr:
    groups["codes"] = scaled(tc.appearance_lr)
  if tc.network_lr > 0 and tc.network_lr != tc.lr:
    groups["network"] = scaled(tc.network_lr)
  if len(groups) == 1:
    return adam
  return optax.multi_transform(groups, functools.partial(_parameter_groups, groups))


def _parameter_groups(groups, params):
  """The optimiser group of `params`' parts: 'poses' for params['poses'], 'codes' for the leaves
  named 'appearance' where `groups` has codes, 'network' for the MLP's 'kernel' and 'bias'
  leaves where it has network, else 'field'. Labels stay a prefix of the tree
  where they can (a whole network is 'field'), as checkpoints of pose refinement saved them."""
  def label(path):
    name = getattr(path[-1], "key", None)
    if name == "appearance" and "codes" in groups:
      return "codes"
    return "network" if name in ("kernel", "bias") and "network" in groups else "field"

  def network(tree):
    if "codes" not in groups and "network" not in groups:
      return "field"
    return jax.tree_util.tree_map_with_path(lambda path, _: label(path), tree)
  return {name: "poses" if name == "poses" else network(tree) for name, tree in params.items()}


# Encoding fields that do not fix the parameters' shapes or meaning (left out of the signature).
_HASHED_LEVELS = ("density_hash_resolution", "density_hash_log2_size",
                  "colour_hash_resolution", "colour_hash_log2_size")
_NOT_IN_SIGNATURE = ("gather_dtype", "density_resolutions", *_HASHED_LEVELS)


def model_signature(config):
  """Config fields that fix the parameter shapes; a checkpoint only restores under the same.

  Keys keep the flat names checkpoints have always stored (grid_resolutions, hash_levels...), so
  checkpoints of earlier versions still restore.
  """
  m = config.model
  signature = {"pos_encode_dims": config.pos_encode_dims,
               "dir_encode_dims": config.dir_encode_dims, "depth": m.depth, "width": m.width,
               "skip_layers": list(m.skip_layers), "view_dependent": m.view_dependent,
               "view_width": m.view_width,
               "networks": list(make_ray_renderer(config).networks)}
  flat = lambda section: {f"{section}_{k}": list(v) if isinstance(v, tuple) else v
                          for k, v in m[section].items() if k not in _NOT_IN_SIGNATURE}
  if m.encoding != "posenc":  # only then, so older checkpoints stay valid
    signature.update(encoding=m.encoding, **flat("grid"))
  if m.encoding in ("hash", "tensorf"):  # the tables' shapes and the meaning of their rows
    signature.update(flat(m.encoding))
  if config.occupancy.enabled:
    signature.update(occupancy_resolution=config.occupancy.resolution)
  if m.appearance_dims:  # only then, so older checkpoints stay valid
    signature.update(appearance_dims=m.appearance_dims)
  if config.train.pose_refinement:
    signature.update(pose_refinement=True)
  if m.grid_box:  # only then, so older checkpoints stay valid
    signature.update(grid_box=list(m.grid_box))
  if tuple(m.grid_cell_aspect) != (1.0, 1.0, 1.0):  # likewise
    signature.update(grid_cell_aspect=list(m.grid_cell_aspect))
  if m.encoding == "grid" and m.grid.density_resolutions:  # likewise
    signature.update(grid_density_resolutions=list(m.grid.density_resolutions))
    for part in ("density", "colour"):  # likewise
      if m.grid[f"{part}_hash_resolution"]:
        signature[f"grid_{part}_hash"] = [m.grid[f"{part}_hash_resolution"],
                                          m.grid[f"{part}_hash_log2_size"]]
  return signature


def init_state(exp):
  """A fresh TrainState of `exp` (parameters from config.seed)."""
  buffers = exp.renderer.init(jax.random.PRNGKey(exp.config.seed))
  params = buffers.pop("params")
  if exp.config.train.pose_refinement:  # a correction per training image, zero = as given
    params["poses"] = jnp.zeros((len(exp.train_ds), 6), jnp.float32)
  if exp.hull is not None:  # sample only inside the hull from the first step, and ever after
    # Two arrays, not one: the train step donates its state, and a buffer is donated once.
    buffers.update(occupancy=jnp.array(exp.hull), hull=jnp.array(exp.hull))
  return TrainState(step=jnp.array(0, jnp.int32), params=params, opt_state=exp.tx.init(params),
                    bad_step=jnp.array(-1, jnp.int32), buffers=buffers)


def upgrade_state_dict(state):
  """A saved TrainState dict (checkpoints.py) of an earlier version made current: the
  occupancy grid once lived in params['occupancy'] (with Adam moments that stayed zero); it
  now lives in buffers."""
  if "buffers" in state:
    return state
  state = dict(state, params=dict(state["params"]), buffers={})
  if "occupancy" in state["params"]:
    state["buffers"]["occupancy"] = state["params"].pop("occupancy")
  state["opt_state"] = _without_occupancy(state["opt_state"])
  return state


def _without_occupancy(tree):
  """`tree` (nested dicts) without the 'occupancy' entry of any dict that holds 'coarse'."""
  if not isinstance(tree, dict):
    return tree
  return {k: _without_occupancy(v) for k, v in tree.items()
          if not (k == "occupancy" and "coarse" in tree)}


def state_template(exp):
  """The structure of `init_state` (shapes and dtypes, nothing computed): what a checkpoint
  restores into, in a fraction of a second instead of initialising every parameter eagerly."""
  return jax.eval_shape(lambda: init_state(exp))


def restore(workdir, with_meta=False):
  """(Experiment, TrainState[, meta]) of the newest checkpoint in `workdir`, under the config
  the run saved (completed with today's defaults, see config_lib.load_saved)."""
  config = config_lib.load_saved(workdir)
  path = checkpoints.latest_path(workdir)
  if path is None:
    raise TrainingError(f"no checkpoint in {checkpoints.checkpoint_dir(workdir)}: "
                        "train first (python train.py --workdir=...)")
  exp = setup(config)
  state, meta = checkpoints.restore_with_meta(path, state_template(exp), model_signature(config),
                                              upgrade_state_dict)
  return (exp, state, meta) if with_meta else (exp, state)
