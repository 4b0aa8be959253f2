"""The learning-rate schedule and the optimiser of a run: Adam with warm-up and exponential
decay, and its parameter groups (poses, appearance codes, network). It reads no config: the
entry layer builds `OptimizerSettings` from config.train (run/builders.optimizer_settings).
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import optax

from nerf_jax.backend import components


@dataclasses.dataclass(frozen=True)
class OptimizerSettings:
  """The optimiser's settings: config.train's fields of the optimiser, and four the entry
  layer derives (run/builders.optimizer_settings): planned_steps (train.max_steps, else
  train.default_steps), pose_refinement (train.pose_refinement: the corrections get their own
  Adam at pose_lr), intrinsics_refinement (train.intrinsics_refinement: the focal scales and
  the lens get their own Adam at intrinsics_lr) and appearance_codes (model.appearance_dims >
  0: the codes get their own Adam at appearance_lr, unless it is lr)."""
  planned_steps: int = components.derived()
  lr: float = 5e-3  # initial Adam learning rate
  lr_final: float = 1e-4  # learning rate at max_steps (exponential decay)
  warmup_steps: int = 50  # linear warm-up from 0
  grad_clip: float = 0.0  # clip gradients to this global norm (0 = off)
  adam_b2: float = 0.999  # Adam's second-moment decay (instant-ngp uses 0.99 for its tables)
  adam_eps: float = 1e-8  # Adam's denominator floor, sqrt(v) + eps (instant-ngp: 1e-15)
  network_l2: float = 0.0  # L2 on the networks' weight matrices, in their gradient (0 = off)
  network_lr: float = 0.0  # the MLP's Adam learning rate on the same schedule (0 = train.lr)
  appearance_lr: float = 3e-4  # appearance codes: Adam learning rate (the field's schedule)
  pose_lr: float = 3e-4  # pose refinement: Adam learning rate of the corrections (same decay)
  intrinsics_lr: float = 1e-3  # intrinsics refinement: Adam learning rate (same decay)
  pose_refinement: bool = components.derived(False)
  intrinsics_refinement: bool = components.derived(False)
  appearance_codes: bool = components.derived(False)

  def __post_init__(self):
    if self.network_l2 < 0:
      raise ValueError(f"config.train.network_l2={self.network_l2}: use 0 (off) or a positive "
                       "weight, e.g. instant-ngp's 1e-6")


def make_schedule(settings, planned_steps=None):
  """count -> learning rate: linear warm-up from 0 to `lr` over `warmup_steps`, then exponential
  decay reaching `lr_final` at the planned steps and staying there (a time-budget run may take a
  few more). settings: OptimizerSettings.

  planned_steps: None for settings.planned_steps, or an int32 [] (possibly traced: a time
  budget's fitted length, see budget.py, so one compiled step serves any length), over which
  warm-up keeps its share of the settings' planned steps (as train_lib.fit_schedule).
  """
  tc = settings
  planned, warmup = tc.planned_steps, tc.warmup_steps
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


def make_optimizer(settings, planned_steps=None):
  """Adam on the schedule (see `make_schedule`; settings: OptimizerSettings, planned_steps as
  there), with optional global-norm gradient clipping.
  With pose_refinement the camera corrections (params['poses']) have an Adam of their own, on
  the same schedule scaled to pose_lr; with intrinsics_refinement the focal scales and the lens
  (params['intrinsics']) too, scaled to intrinsics_lr; with appearance_codes (every parameter named
  'appearance'), so do the codes, scaled to appearance_lr (unless it is lr: one Adam, as in
  runs saved before train.appearance_lr existed); with network_lr, the MLP's layers (leaves
  'kernel' and 'bias'), scaled to it. With network_l2 = λ, λ·w is added to the gradient of
  each weight matrix w (`network_matrices`) before its Adam (a coupled L2, as instant-ngp's
  `l2_reg`, not AdamW's decoupled decay)."""
  tc = settings
  schedule = make_schedule(tc, planned_steps)
  adam_on = lambda rate: optax.adam(rate, b2=tc.adam_b2, eps=tc.adam_eps)
  adam = adam_on(schedule)
  if tc.grad_clip > 0:
    adam = optax.chain(optax.clip_by_global_norm(tc.grad_clip), adam)
  scaled = lambda lr: adam_on(lambda count: lr / tc.lr * schedule(count))
  groups = {"field": adam}
  if tc.pose_refinement:
    groups["poses"] = scaled(tc.pose_lr)
  if tc.intrinsics_refinement:
    groups["intrinsics"] = scaled(tc.intrinsics_lr)
  if tc.appearance_codes and tc.appearance_lr != tc.lr:
    groups["codes"] = scaled(tc.appearance_lr)
  if tc.network_lr > 0 and tc.network_lr != tc.lr:
    groups["network"] = scaled(tc.network_lr)
  tx = adam if len(groups) == 1 else optax.multi_transform(
      groups, functools.partial(_parameter_groups, groups))
  if tc.network_l2 > 0:
    tx = optax.chain(optax.add_decayed_weights(tc.network_l2, mask=network_matrices), tx)
  return tx


def network_matrices(params):
  """bool per leaf of `params`: the networks' weight matrices (leaves named 'kernel'), what
  train.network_l2 regularises. Not the biases, the lattice and hash tables (instant-ngp keeps
  its tables free of L2: a row few rays reach would shrink between their visits), the camera
  corrections or the appearance codes."""
  matrix = lambda path, _: getattr(path[-1], "key", None) == "kernel"
  return jax.tree_util.tree_map_with_path(matrix, params)


def _parameter_groups(groups, params):
  """The optimiser group of `params`' parts: 'poses' for params['poses'], 'intrinsics' for
  params['intrinsics'], 'codes' for the leaves named 'appearance' where `groups` has codes,
  'network' for the MLP's 'kernel' and 'bias' leaves where it has network, else 'field'. Labels
  stay a prefix of the tree where they can (a whole network is 'field'), as checkpoints of pose
  refinement saved them."""
  def label(path):
    name = getattr(path[-1], "key", None)
    if name == "appearance" and "codes" in groups:
      return "codes"
    return "network" if name in ("kernel", "bias") and "network" in groups else "field"

  def network(tree):
    if "codes" not in groups and "network" not in groups:
      return "field"
    return jax.tree_util.tree_map_with_path(lambda path, _: label(path), tree)
  own = ("poses", "intrinsics")  # groups of their own, by top-level name
  return {name: name if name in own else network(tree) for name, tree in params.items()}
