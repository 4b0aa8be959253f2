"""The recommended setup: train on the built-in `diffuse` scene in a few minutes on a 2-core CPU.

  python train.py --config=configs/default.py --workdir=runs/default
  python train.py --config=configs/default.py --config.num_samples=128 --workdir=runs/s128
"""

import ml_collections

from nerf_jax.backend import components
from nerf_jax.evaluate import evaluation
from nerf_jax.fields import protocol
from nerf_jax.fields.encodings import grid, hashgrid, posenc, tensorf
from nerf_jax.fields.networks import mlp
from nerf_jax.fields.networks import transient as transient_head
from nerf_jax.samplers import occupancy, proposal
from nerf_jax.train.losses import (colour, distortion, pose_prior, robust, total_variation,
                                    transient)


def _section(term):
  """A loss term module's config section: its Settings' fields at their defaults."""
  return ml_collections.ConfigDict(components.section(term.Settings))


def get_config():
  config = ml_collections.ConfigDict()
  config.seed = 0  # PRNG seed for initialisation, ray batches and jitter
  config.num_samples = 32  # NUM_SAMPLES: stratified (coarse) samples per ray
  config.num_fine_samples = 0  # extra samples drawn from the coarse weights (0 = no hierarchy)
  config.sampler = ""  # '' = stratified / occupancy placement; 'proposal' (config.proposal)
  # Settings declared, each with its comment, in the dataclass of the part that owns it:
  # pos_encode_dims (POS_ENCODE_DIMS, the positions' bands): fields/encodings/posenc.Settings;
  # dir_encode_dims, dir_encoding (the viewing directions'): fields/protocol.DirectionSettings.
  config.update(components.section(posenc.Settings))
  config.update(components.section(protocol.DirectionSettings))
  config.auto = False  # decide the effects and the representation from the data (configs/auto.py)
  config.auto_decisions = ()  # what auto decided and why, one line each (filled by auto)
  config.auto_flags = ()  # fields set on the command line (filled by nerf-train): auto keeps them

  config.data = data = ml_collections.ConfigDict()
  data.path = ""  # dataset: .npz, Blender, LLFF or transforms.json folder; empty = built-in scene
  data.scene = "diffuse"  # built-in scene name (see nerf_jax/scenes)
  data.num_views = 100  # built-in scene: number of rendered views
  data.image_size = 100  # built-in scene: height = width in pixels
  data.holdout_from = -1  # views[holdout_from:] are test views; -1 = the reference's 80/20 split
  data.held_out_looks = "neutral"  # per-photo-look scenes: test views 'neutral' or 'own' looks
  data.pixel_center = -1.0  # -1 = the data's own (0.5 centres; 0 corners for tiny_nerf .npz)
  data.background = "black"  # 'black', 'white' or an RGB triple: rendered and scored on
  data.half_res = False  # Blender data: load at half resolution
  data.factor = 1  # LLFF and transforms.json data: downsample images by this integer factor
  data.bd_factor = 0.75  # LLFF data: scale so the nearest bound is 1/bd_factor (0 = keep units)
  data.recenter = True  # LLFF data: move the mean camera pose to the origin
  data.min_sharpness = 0.0  # transforms.json: drop frames < this x neighbours' sharpness (0 = off)
  data.lindisp = False  # sample linearly in inverse depth instead of depth
  data.ndc = False  # forward-facing scenes: rays in normalized device coordinates, t in [0, 1]
  data.near = 0.0  # near bound override (0 = the dataset's, 2 for tiny_nerf)
  data.far = 0.0  # far bound override (0 = the dataset's, 6 for tiny_nerf)
  data.scene_bound = 0.0  # half-size of the box sampled (0 = none, -1 = found from the data)
  data.visual_hull = False  # data with opacity: carve the masks' hull; grids and samples fit it
  data.contraction = ""  # unbounded scene: 'linf' or 'l2' contracts the space beyond the box
  data.inner_fraction = 0.5  # unbounded scene: share of samples inside the box (the rest beyond)
  data.focus = False  # move the world so that the point the cameras look at is the origin

  config.model = model = ml_collections.ConfigDict()
  model.encoding = "posenc"  # positions: 'posenc' (bands), 'grid' (fast.py), 'hash', 'tensorf'
  model.network = ""  # the network reading them: '' = the encoding's own ('mlp', 'lattice'), a name
  model.grid_bound = 1.5  # grid and hash encodings: the grids cover [-bound, bound]^3
  model.grid_box = ()  # grid encodings: (min x, y, z, max x, y, z) of a tighter box; () = cube
  model.grid_cell_aspect = (1.0, 1.0, 1.0)  # grid and tensorf: relative x, y, z sides of a cell
  # Each section below is the Settings dataclass of its part, every field with its comment there.
  model.grid = ml_collections.ConfigDict(components.section(grid.Settings))  # encodings/grid.py
  model.hash = ml_collections.ConfigDict(components.section(hashgrid.Settings))  # hashgrid.py
  model.tensorf = ml_collections.ConfigDict(components.section(tensorf.Settings))  # tensorf.py
  model.update(components.section(mlp.Settings))  # depth, width, skip_layers: networks/mlp.py
  model.view_dependent = False  # colour depends on the viewing direction (paper's 5D input)
  model.view_width = 32  # width of the view-dependent colour layer
  model.view_depth = 1  # colour layers of view_width after the direction joins (instant-ngp: 2)
  model.density_activation = "relu"  # 'relu' (reference), 'softplus' (shifted) or 'exp'
  model.density_noise = 0.0  # std of noise added to raw density while training (paper: 1)
  model.colour_fraction = 0.0  # density grid: colour only for this share of samples (top weights)
  model.shared_fine = False  # one network for coarse and fine passes instead of two
  model.dtype = "float32"  # matmul dtype: float32, bfloat16 or float16
  model.matmul_precision = "default"  # networks' f32 matmuls: default (TF32 on GPUs), high, highest
  model.appearance_dims = 0  # per-training-image appearance code (GLO) for colour; 0 = off
  # NeRF-W's transient head (dims 0 = off): its Settings, networks/transient.py
  model.transient = ml_collections.ConfigDict(components.section(transient_head.Settings))

  # The occupancy grid: `enabled`, then its Settings (samplers/occupancy.OccupancySettings).
  config.occupancy = occ = ml_collections.ConfigDict()
  occ.enabled = False  # sample only in occupied cells of a grid over data.scene_bound's box
  occ.update(components.section(occupancy.OccupancySettings))

  # config.sampler = 'proposal': its section, every field with its comment, is the Settings
  # dataclass of nerf_jax/samplers/proposal.py.
  config.proposal = ml_collections.ConfigDict(components.section(proposal.Settings))

  # The loss terms (nerf_jax/train/losses/, docs/extending.md): each has its section
  # config.loss.<name>, whose fields, defaults and comments are its module's Settings.
  config.loss = loss = ml_collections.ConfigDict()
  loss.terms = ("colour", "distortion", "pose_prior", "total_variation", "transient",
                "robust")  # added in this order
  loss.colour = _section(colour)  # photometric loss (always on): weight, coarse_weight, huber_delta
  loss.distortion = _section(distortion)  # mip-NeRF 360's distortion loss: weight (0 = off)
  loss.pose_prior = _section(pose_prior)  # pose refinement: pull toward no correction: weight
  loss.total_variation = _section(total_variation)  # lattice tables' smoothness: weight
  loss.transient = _section(transient)  # NeRF-W's uncertainty loss (on with model.transient.dims)
  loss.robust = _section(robust)  # RobustNeRF's trimmed loss: weight > 0 switches it on (patches)

  config.train = train = ml_collections.ConfigDict()
  train.max_steps = 0  # step budget (0 = fitted to max_seconds if set, else default_steps)
  train.max_seconds = 0.0  # wall-clock budget in seconds; alone, the run lasts exactly this long
  train.default_steps = 2500  # step budget when neither max_steps nor max_seconds is set
  train.batch_rays = 512  # rays per step (random rays over all training images)
  train.sample_budget = 0  # occupancy: samples a step queries (valid ones, compacted); 0 = all
  train.batching = "rays"  # 'rays' (random rays), 'images' (whole), 'patches' (loss.robust: always)
  train.images_per_step = 5  # whole images per step when batching == 'images'
  train.image_order = "random"  # 'images' batching: 'random' draws per step, 'epochs' shuffles
  train.patch_size = 16  # patches (loss.robust on): batch_rays // patch_size² squares a step
  train.lr = 5e-3  # initial Adam learning rate
  train.lr_final = 1e-4  # learning rate at max_steps (exponential decay)
  train.warmup_steps = 50  # linear warm-up from 0
  train.grad_clip = 0.0  # clip gradients to this global norm (0 = off)
  train.adam_b2 = 0.999  # Adam's second-moment decay (instant-ngp uses 0.99 for its tables)
  train.adam_eps = 1e-8  # Adam's denominator floor, sqrt(v) + eps (instant-ngp: 1e-15)
  train.network_l2 = 0.0  # L2 on the networks' weight matrices, in their gradient (0 = off)
  train.ema_decay = 0.0  # score and render the weights' moving average of this decay (0 = off)
  train.network_lr = 0.0  # the MLP's Adam learning rate on the same schedule (0 = train.lr)
  train.remat_chunk = 128  # rays per cache-sized, recomputed field chunk in a step (0 = off)
  train.random_background = False  # data with opacity: composite on random colours (no floaters)
  train.pose_refinement = False  # learn an SE(3) correction of each training camera (BARF)
  train.appearance_lr = 3e-4  # appearance codes: Adam learning rate (the field's schedule)
  train.pose_lr = 3e-4  # pose refinement: Adam learning rate of the corrections (same decay)
  train.pose_coarse_to_fine = (0.1, 0.5)  # bands (grid levels) open between these shares of steps
  train.pose_ray_share = 1.0  # pose refinement: share of a batch's rays that move the poses
  train.log_every = 100  # steps between progress lines and metrics.jsonl records
  train.eval_every = 0  # steps between test-view evaluations (0 = only at the end)
  train.eval_views = 2  # test views rendered for periodic evaluations (the final one uses all)
  train.checkpoint_every = 500  # steps between checkpoints
  train.keep_checkpoints = 2  # checkpoints kept in the workdir
  train.data_parallel = True  # split each batch over all devices (no-op on one device)
  train.tensorboard = True  # write TensorBoard events into <workdir>/tb
  train.deterministic = False  # repeatable GPU runs: XLA's deterministic ops (CPUs repeat anyway)

  config.render = render = ml_collections.ConfigDict()
  render.chunk = 4096  # rays per jitted render call
  render.march = True  # skip empty space, stop at opaque surfaces (scene-box single-pass models)
  render.march_grid = 48  # cells per side of the skip grid computed from the trained density
  render.march_threshold = 0.1  # density (per scene unit) below which a cell is skipped
  render.march_probes = 4  # skip-grid probes per cell side: keeps structure >= √3/4 cell thick
  render.march_group = 16  # samples per ray offered in each marching round
  render.min_transmittance = 1e-4  # a ray stops once less light than this gets through
  render.num_samples = 0  # samples per ray when rendering (0 = num_samples, as in training)
  render.video_frames = 60  # frames in the 360° orbit video (0: no video after training)
  render.video_path = "auto"  # 'orbit' (NDC: spiral), 'trajectory' (the capture's); auto: by data
  render.fps = 30  # video frame rate
  render.orbit_phi = -30.0  # orbit elevation in degrees
  render.orbit_radius = 4.0  # orbit distance from the origin
  render.after_training = True  # train.py renders test views and the video when done

  # How held-out views are scored: `appearance` ('mean' | 'left_half': NeRF-W's code fitted on
  # each test image's left half, scored on its right half) and the fit's steps, rays and step
  # size; each field with its comment in the Settings dataclass of nerf_jax/evaluate/evaluation.py.
  config.eval = ml_collections.ConfigDict(components.section(evaluation.Settings))

  config.viewer = viewer = ml_collections.ConfigDict()
  viewer.enabled = False  # serve the live viewer (viser) while training: pip install -e ".[viewer]"
  viewer.port = 7007  # port of the live viewer's page (http://localhost:PORT)
  return config
