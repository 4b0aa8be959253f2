"""What a run's checkpoints record, from its config: the model signature (the shared fields,
then the encoding's and the sampler's entries), a fresh TrainState (train/state.py) and its
template, the shapes a checkpoint restores into (states of earlier versions are upgraded by
train/state.upgrade_state_dict).
"""


import jax
import jax.numpy as jnp

from nerf_jax.backend import components
from nerf_jax.cameras import intrinsics_refinement
from nerf_jax.fields import registry
from nerf_jax.fields.encodings import grid
from nerf_jax.render import renderer
from nerf_jax.train.state import TrainState
from nerf_jax.run.builders import (encoding_family, make_ray_renderer, make_sampler,
                                     network_family, own_settings, transient_settings)


def model_signature(config):
  """Config fields that fix the parameter shapes; a checkpoint only restores under the same.

  The shared fields (the positions' bands, the directions', the MLP's settings: recorded
  whatever the encoding, as they always were), then the encoding's own entries
  (registry.Encoding.signature), then the optional parts, each only when on so that checkpoints
  saved before it existed stay valid. Keys keep the flat names checkpoints have always stored
  (grid_resolutions, hash_levels...); each derives from the settings dataclass that declares it
  (components.signature).
  """
  m = config.model
  encodings, networks = registry.ENCODINGS, registry.NETWORKS
  posenc, mlp = encodings.lookup("posenc"), networks.lookup("mlp")
  mlp_settings = own_settings(networks, mlp, config)
  signature = {**components.signature(own_settings(encodings, posenc, config), ""),
               "dir_encode_dims": config.dir_encode_dims,
               "depth": mlp_settings.depth, "width": m.width,
               "skip_layers": list(mlp_settings.skip_layers),
               "view_dependent": m.view_dependent, "view_width": m.view_width,
               "networks": list(make_ray_renderer(config).networks)}
  family, settings = encoding_family(config)
  if family.records_grid_section:
    grid_settings = own_settings(encodings, encodings.lookup("grid"), config)
    signature.update(grid.lattice_signature(grid_settings))
  signature.update(family.entries(settings))
  network, network_settings = network_family(config)
  if config.model.network and config.model.network != family.natural_network(settings):
    signature.update(network=network.name)  # another network than the encoding's own
  if network.name != "mlp":  # the MLP's settings are among the shared fields above
    signature.update(network.entries(network_settings))
  if config.occupancy.enabled:
    signature.update(occupancy_resolution=config.occupancy.resolution)
  if m.view_depth != 1:
    signature.update(view_depth=m.view_depth)
  if config.dir_encoding != "frequency":
    signature.update(dir_encoding=config.dir_encoding)
  if m.appearance_dims:
    signature.update(appearance_dims=m.appearance_dims)
  transient = transient_settings(config)
  if transient.dims:  # only then, so the signatures of runs without the head stay as they were
    signature.update(components.signature(transient, "transient_",
                                          exclude=("beta_min", "density_shift")))
  if config.train.pose_refinement:
    signature.update(pose_refinement=True)
  if config.train.intrinsics_refinement:  # params['intrinsics']
    signature.update(intrinsics_refinement=True)
  if config.train.ema_decay > 0:  # the state holds the weights' moving average
    signature.update(ema=True)
  if m.grid_box:
    signature.update(grid_box=list(m.grid_box))
  if tuple(m.grid_cell_aspect) != (1.0, 1.0, 1.0):
    signature.update(grid_cell_aspect=list(m.grid_cell_aspect))
  signature.update(make_sampler(config).signature())  # a learned sampler's ({}: the built-in)
  return signature


def init_state(exp):
  """A fresh TrainState of `exp` (parameters from config.seed)."""
  buffers = exp.renderer.init(jax.random.PRNGKey(exp.config.seed))
  params = buffers.pop("params")
  if exp.config.train.pose_refinement:  # a correction per training image, zero = as given
    params["poses"] = jnp.zeros((len(exp.train_ds), 6), jnp.float32)
  if exp.config.train.intrinsics_refinement:  # focal scales and a lens, zeros = as given
    params["intrinsics"] = intrinsics_refinement.initial(len(exp.train_ds))
  if exp.hull is not None:  # no density outside the hull (renderer.py), from the first step
    grid, bound = exp.hull
    buffers.update(hull=jnp.array(grid), hull_bound=jnp.asarray(bound, jnp.float32))
    if exp.config.occupancy.enabled:  # and samples only inside it, from the first step
      # A new array, not the hull's: the train step donates its state, a buffer once.
      buffers.update(occupancy=renderer.occupancy_hull(exp.renderer.sampler, buffers["hull"],
                                                       buffers["hull_bound"]))
  ema = {}
  if exp.config.train.ema_decay > 0:  # the average starts at the initial weights
    # Copies, not the same arrays: the train step donates its state, and a buffer once.
    ema = {"params": jax.tree_util.tree_map(jnp.array, params)}
  return TrainState(step=jnp.array(0, jnp.int32), params=params, opt_state=exp.tx.init(params),
                    bad_step=jnp.array(-1, jnp.int32), buffers=buffers, ema=ema)


def state_template(exp):
  """The structure of `init_state` (shapes and dtypes, nothing computed): what a checkpoint
  restores into, in a fraction of a second instead of initialising every parameter eagerly."""
  return jax.eval_shape(lambda: init_state(exp))
