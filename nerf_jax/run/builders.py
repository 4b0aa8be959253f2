"""Each layer's settings and components, built from the config once (the entry layer's job:
nothing below run/ reads a config): the data's, the field (its encodings and network), the sampler
(by name), the renderers, the train step with its loss terms and hooks, the evaluator.
"""

import dataclasses
import functools

import ml_collections

from nerf_jax.backend import components, precision
from nerf_jax.fields import field as field_lib
from nerf_jax.fields import protocol, registry
from nerf_jax.fields import transient_field
from nerf_jax.fields.networks import transient_head
from nerf_jax.run import config_lib
from nerf_jax.samplers import occupancy
from nerf_jax.samplers import registry as sampler_registry
from nerf_jax.render import background, renderer
from nerf_jax.train import losses, optimizer, train_batches, train_step
from nerf_jax.train.losses import colour, robust
from nerf_jax.data.data_settings import DataSettings
from nerf_jax.evaluate import evaluation
from nerf_jax.fields.field import Field
from nerf_jax.fields.protocol import NetworkSettings
from nerf_jax.render.image_renderer import ImageSettings
from nerf_jax.render.renderer import RayRenderer
from nerf_jax.samplers.placement import Sampler


def data_settings(data):
  """The DataSettings of a `data` section (config.data: a ConfigDict or dict; the fields it lacks
  take their defaults, old spellings are moved: config_lib.complete)."""
  saved = data.to_dict() if hasattr(data, "to_dict") else dict(data)
  data = config_lib.complete({"data": saved}).data
  return components.settings_from(DataSettings, data.to_dict(), "data", strict=False)


def shared_settings(settings_class, config, path, **derived):
  """settings_class built from the shared section of `config` at dotted `path` (the fields it
  declares; `check_config` has refused the keys nobody declares) and the `derived` fields."""
  return components.settings_from(settings_class, config_lib.section_at(config, path).to_dict(),
                                  path, strict=False, **derived)


def own_settings(reg, record, config):
  """`record`'s settings (reg: its components.Registry) built from its section of `config`
  (Registry.section_path); None if it has none; ValueError naming the field if wrong."""
  values = config_lib.section_at(config, reg.section_path(record))
  return reg.settings(record, None if values is None else values.to_dict())


def check_config(config):
  """ValueError naming the first key of `config` that no settings dataclass declares: a
  misspelt setting (run/schema.SECTIONS for the shared sections; each component's own
  section is read strictly when it is built)."""
  for path, classes in config_lib.SECTIONS.items():
    values = config_lib.section_at(config, path)
    if values is None:
      continue
    nested = [k for k, v in values.items() if isinstance(v, (dict, ml_collections.ConfigDict))]
    components.check_section(values, path, classes, subsections=nested)


def encoding_family(config):
  """The position encoding (registry.Encoding) config.model.encoding names, and its settings
  built from its own section (config.model.<name>); ValueError naming the field if either is
  wrong."""
  record = registry.ENCODINGS.lookup(config.model.encoding)
  return record, own_settings(registry.ENCODINGS, record, config)


def network_settings(config, num_images=1):
  """fields.protocol.NetworkSettings of config.model (num_images: see `make_field`)."""
  settings = shared_settings(NetworkSettings, config, "model",
                             appearance_images=max(int(num_images), 1))
  if config.data.contraction:
    # In an unbounded scene the grids cover the whole contracted space, twice the inner box.
    settings = dataclasses.replace(settings, grid_bound=2.0 * config.data.scene_bound)
  return settings


def network_name(config):
  """The name of the network that reads config.model.encoding: config.model.network, or ''
  for the encoding's own (registry.Encoding.network)."""
  record, settings = encoding_family(config)
  return config.model.network or record.natural_network(settings)


def network_family(config):
  """The network (registry.Network) that reads the encoding (`network_name`), and its settings
  built from its section (None if it has none); ValueError naming the field if wrong."""
  record = registry.NETWORKS.lookup(network_name(config))
  return record, own_settings(registry.NETWORKS, record, config)


def make_field(config, num_images=1):
  """The Field of `config.model` (and the top-level encoding fields): the position encoding
  `model.encoding` names (fields/registry.py), built from its own section (model.grid,
  model.hash, ...), read by the network `model.network` names (or the encoding's own), and the
  direction encoding `dir_encoding` names. num_images: training images, the rows of the
  appearance codes' table (model.appearance_dims > 0)."""
  check_config(config)
  m = config.model
  record, settings = encoding_family(config)
  if m.appearance_dims < 0:
    raise ValueError(f"config.model.appearance_dims={m.appearance_dims}: use 0 (off) or the "
                     "length of each training image's appearance code (e.g. 8)")
  precision.network_precision(m.matmul_precision)  # ValueError naming the field if unknown
  shared = network_settings(config, num_images)
  net_record, net_settings = network_family(config)
  network = net_record.build(record.build(settings, shared), net_settings, shared)
  if not isinstance(network, protocol.Network):
    raise TypeError(f"network {net_record.name!r}: {type(network).__name__} lacks "
                    "coarse_to_fine_stages, band_weights or splits_density (fields/protocol.py)")
  dirs = registry.DIRECTION_ENCODINGS
  dir_record = dirs.lookup(config.dir_encoding)
  directions = dir_record.build(own_settings(dirs, dir_record, config), shared)
  noise = shared_settings(field_lib.Settings, config, "model").density_noise
  return Field(network, directions, m.view_dependent, m.density_activation, noise,
               config.data.contraction, max(config.data.scene_bound, 1e-6), m.appearance_dims,
               cones=record.cone_kind(settings))


def make_sampler(config):
  """The sampler config.sampler names (samplers/registry.py; '' = the built-in placement),
  built from the built-in Sampler of `config` (samples, scene box, spacing, occupancy) and its
  own config section (config.<name>, e.g. config.proposal); ValueError naming the field when a
  setting cannot work with the rest."""
  oc = config.occupancy
  if oc.enabled:
    if (config.data.scene_bound <= 0 and config.data.scene_bound != -1
        and not config.data.ndc):
      raise ValueError("config.occupancy.enabled needs config.data.scene_bound > 0 or -1 "
                       "(auto): the grid covers that box")
    if config.num_fine_samples > 0:
      raise ValueError("config.occupancy.enabled and config.num_fine_samples > 0 cannot be "
                       "combined: the occupancy grid already places the samples; set one of "
                       "them")
    if config.data.ndc and config.data.scene_bound != 0:
      raise ValueError("config.occupancy.enabled with config.data.ndc needs "
                       "config.data.scene_bound = 0: the grid covers the training rays' NDC "
                       "box (model.grid_box)")
  settings = shared_settings(occupancy.OccupancySettings, config, "occupancy")
  if config.data.contraction:
    if config.data.scene_bound <= 0 and config.data.scene_bound != -1:
      raise ValueError("config.data.contraction needs config.data.scene_bound > 0 or -1 "
                       "(auto): the inner region's half-size")
    if config.data.ndc or config.num_fine_samples > 0:
      raise ValueError("config.data.contraction does not work with config.data.ndc or "
                       "config.num_fine_samples > 0 yet")
  base = Sampler(config.num_samples, config.data.scene_bound, config.data.lindisp,
                 settings if oc.enabled else None, config.data.contraction,
                 config.data.inner_fraction, occupancy_box(config))
  record = sampler_registry.record(config.sampler)
  if record.name != sampler_registry.BUILTIN and (config.num_fine_samples > 0
                                                  or config.data.ndc):
    raise ValueError(f"config.sampler={config.sampler!r} places the samples itself: set "
                     "config.num_fine_samples=0 (and it does not work with config.data.ndc)")
  return record.build(own_settings(sampler_registry.REGISTRY, record, config), base)


# NDC's nominal box: the reference camera's frustum, before the data gives the real one.
NDC_CUBE = (-1.0, -1.0, -1.0, 1.0, 1.0, 1.0)


def occupancy_box(config):
  """The box an NDC run's occupancy grid covers: model.grid_box (the training rays' box,
  from_data.with_ndc_box), or NDC_CUBE before the data has set it; None for other runs (the
  grid covers the scene's cube)."""
  if not (config.data.ndc and config.occupancy.enabled):
    return None
  return tuple(float(v) for v in config.model.grid_box) or NDC_CUBE


def make_ray_renderer(config, num_images=1):
  """The RayRenderer of `config`: its field, its sampler and the fine pass (num_images: see
  `make_field`). Its sample budget is 0 (every slot): training sets config.train.sample_budget
  (`training_renderer`)."""
  if config.train.sample_budget and not config.occupancy.enabled:
    raise ValueError("config.train.sample_budget needs config.occupancy.enabled: the budget "
                     "is spent on the samples the occupancy grid places (0 = off)")
  use = shared_settings(renderer.Settings, config, "model")
  return RayRenderer(make_field(config, num_images), make_sampler(config),
                     config.num_fine_samples, use.shared_fine, use.colour_fraction,
                     transient=make_transient(config, num_images))


def transient_settings(config):
  """networks/transient_head.Settings of config.model.transient (ValueError naming a wrong field)."""
  return components.settings_from(transient_head.Settings, dict(config.model.transient),
                                  "model.transient")


def make_transient(config, num_images=1):
  """NeRF-W's transient field (fields/transient_field.TransientField) of config.model.transient, one
  embedding per training image, or None when its dims is 0; ValueError naming the fields it
  does not work with yet."""
  settings = transient_settings(config)
  if not settings.dims:
    return None
  if config.train.sample_budget or config.model.colour_fraction:
    raise ValueError("config.model.transient.dims > 0 does not work with "
                     "config.train.sample_budget or config.model.colour_fraction yet: set them "
                     "to 0")
  head = transient_head.build(settings, num_images, config.model.dtype,
                              config.model.matmul_precision)
  return transient_field.TransientField(head, settings.beta_min, settings.density_shift)


def training_renderer(exp):
  """exp.renderer with the config's training sample budget (renderer.RayRenderer)."""
  return dataclasses.replace(exp.renderer, sample_budget=exp.config.train.sample_budget)


def image_settings(config):
  """ImageSettings of `config.render` (no marching in NDC: the skip grid is in world space);
  ValueError naming the field for a negative sample count."""
  settings = shared_settings(ImageSettings, config, "render")
  if settings.num_samples < 0:
    raise ValueError(f"config.render.num_samples={settings.num_samples}: use 0 (training's "
                     "num_samples) or a positive count of samples per ray")
  return dataclasses.replace(settings, march=settings.march and not config.data.ndc)


def batch_settings(config):
  """train_batches.BatchSettings of `config.train`; with RobustNeRF's trimmed loss on
  (config.loss.robust.weight > 0) the batches are patches of config.train.patch_size
  (robust.batching: ValueError naming the fields for batching='images')."""
  settings = shared_settings(train_batches.BatchSettings, config, "train")
  return dataclasses.replace(settings, batching=robust.batching(
      settings.batching, config.loss.robust.weight))


def rays_per_step(config, dataset):
  """Rays in one train step of `config` on `dataset`'s images."""
  return train_batches.rays_per_step(batch_settings(config), dataset.height, dataset.width)


def schedule_steps(train_config):
  """The steps the learning-rate schedule spans: max_steps if set, else default_steps."""
  return int(train_config.max_steps or train_config.default_steps)


def optimizer_settings(config):
  """optimizer.OptimizerSettings of config.train (appearance codes: model.appearance_dims)."""
  return shared_settings(optimizer.OptimizerSettings, config, "train",
                         planned_steps=schedule_steps(config.train),
                         pose_refinement=config.train.pose_refinement,
                         intrinsics_refinement=config.train.intrinsics_refinement,
                         appearance_codes=config.model.appearance_dims > 0)


def step_settings(exp):
  """train_step.StepSettings of the run `exp` describes."""
  tc = exp.config.train
  if not 0 <= tc.ema_decay < 1:
    raise ValueError(f"config.train.ema_decay={tc.ema_decay}: use 0 (off) or a decay in "
                     "(0, 1), e.g. instant-ngp's 0.95")
  settings = shared_settings(
      train_step.StepSettings, exp.config, "train", batch=batch_settings(exp.config),
      background=tuple(float(v) for v in background.parse(exp.config.data.background)),
      planned_steps=schedule_steps(tc))
  return dataclasses.replace(settings, random_background=background.trains_on_random(
      tc.random_background, exp.train_ds.accs is not None))


def loss_terms(config, ray_renderer):
  """The train step's loss terms (train/losses/) of `config`: each of config.loss.terms (a
  registered name or a module path, losses.REGISTRY) built from its section config.loss.<name>
  (None from its build: off), then the sampler's own, in the order they are added. ValueError
  naming the field for a term that is unknown, listed twice or without its section, or for
  'colour' missing (the photometric loss is always on). With a transient head
  (config.model.transient.dims > 0) 'transient' is added when the list lacks it. Beside a term
  that replaces the colour term (`replaces_colour`: robust, on at config.loss.robust.weight >
  0) the colour term steps aside: built with weight 0 (its PSNR only), never added to it."""
  names = tuple(config.loss.terms)
  if ray_renderer.transient is not None and "transient" not in names:
    names += ("transient",)  # the transient pass's loss (the colour term leaves that pass)
  if "colour" not in names:
    raise ValueError(f"config.loss.terms={names}: must include 'colour' (the photometric "
                     "loss is always on)")
  if config.loss.robust.weight > 0 and "robust" not in names:
    raise ValueError(f"config.loss.robust.weight={config.loss.robust.weight} needs 'robust' in "
                     f"config.loss.terms={names}: add it, or set the weight to 0")
  batch = batch_settings(config)
  patches = batch.patch_size if batch.batching == "patches" else 0
  context = losses.Context(ray_renderer, tuple(encoding_family(config)[0].table_axes.items()),
                           patch_size=patches, pose_refinement=config.train.pose_refinement)
  terms, seen = [], set()
  for name in names:
    record = losses.REGISTRY.lookup(name)
    if record.name in seen:
      raise ValueError(f"config.loss.terms={names}: term {record.name!r} is listed twice")
    seen.add(record.name)
    term = record.build(own_settings(losses.REGISTRY, record, config), context)
    if term is not None:
      terms.append(term)
  if any(getattr(term, "replaces_colour", False) for term in terms):
    terms = [dataclasses.replace(term, weight=0.0) if isinstance(term, colour.Colour) else term
             for term in terms]
  return terms + ray_renderer.sampler.loss_terms()  # a sampler brings its own (proposal.py)


def train_step_args(exp, mesh=None):
  """The arguments of train_step.make_train_step for the run `exp` describes (mesh: see
  there): the training renderer, the optimiser and its settings for a fitted schedule, the
  loss terms, the StepSettings and the buffer updates (the occupancy grid's refresh)."""
  ray_renderer = training_renderer(exp)
  updates = ()
  if ray_renderer.sampler.occupancy is not None:
    updates = (train_step.OccupancyRefresh(ray_renderer),)
  return dict(ray_renderer=ray_renderer, tx=exp.tx,
              terms=loss_terms(exp.config, ray_renderer), settings=step_settings(exp),
              optimizer_for=functools.partial(optimizer.make_optimizer,
                                              optimizer_settings(exp.config)),
              mesh=mesh, buffer_updates=updates)


def make_train_step(exp, mesh=None):
  """The jitted train step of `exp` (train_step.make_train_step of `train_step_args`)."""
  return train_step.make_train_step(**train_step_args(exp, mesh))


def make_train_data(exp):
  """train_batches.TrainData of exp's training images: targets on config.data.background, each
  step's rays made through the training camera as `Experiment.rays` makes them; with a loss term
  that asks for keypoint rays (losses.keypoint_rays: config.loss.depth) the sparse points'
  keypoints too (ValueError naming the term's weight where the data has no tracks, or none of
  them in front of a training camera)."""
  height, width, intrinsics = exp.camera()
  camera = (height, width, intrinsics, exp.near, exp.far, exp.pixel_center,
            exp.config.data.ndc)
  asking = [t for t in loss_terms(exp.config, training_renderer(exp))
            if getattr(t, "keypoint_rays", 0)]
  field = asking and f"config.loss.{asking[0].name}.weight={asking[0].weight}"
  if asking and exp.train_ds.observations is None:
    raise ValueError(f"{field} needs the sparse points' tracks (a COLMAP model: a COLMAP "
                     "folder, or sparse/0 beside transforms.json or poses_bounds.npy); "
                     f"{exp.config.data.path or 'the built-in scene'} has none: set it to 0")
  data = train_batches.make_train_data(exp.train_ds, camera,
                                       background.parse(exp.config.data.background),
                                       with_radii=exp.renderer.field.cones,
                                       photo_bounds=exp.config.data.photo_bounds,
                                       keypoints=bool(asking))
  if asking and not len(data.keypoints):
    raise ValueError(f"{field}: no observation of a sparse point lies in front of a training "
                     "camera, inside its image and its near..far, unmasked: set it to 0")
  return data


def eval_settings(config):
  """evaluation.EvalSettings of `config` (data.background; config.eval: evaluation.Settings)."""
  return evaluation.EvalSettings(
      background=tuple(float(v) for v in background.parse(config.data.background)),
      held_out=components.settings_from(evaluation.Settings, dict(config.eval), "eval"),
      photo_bounds=config.data.photo_bounds)


def make_evaluator(exp):
  """The evaluator of exp's test views (evaluation.make_evaluator) under `eval_settings`."""
  return evaluation.make_evaluator(exp, eval_settings(exp.config))


def portable(config):
  """A copy of `config` in which every component named by a name added with `register` is
  named by its module path instead, so that restoring the run (config.json, in a process that
  never ran the registering code) finds it again; built-in names stay as they are."""
  config = config.copy_and_resolve_references()
  for field, reg in (("model.encoding", registry.ENCODINGS), ("model.network", registry.NETWORKS),
                     ("dir_encoding", registry.DIRECTION_ENCODINGS),
                     ("sampler", sampler_registry.REGISTRY)):
    value = config_lib.get_field(config, field)
    config_lib.set_field(config, field, reg.added().get(value, value))
  config.loss.terms = tuple(losses.REGISTRY.added().get(n, n) for n in config.loss.terms)
  return config
