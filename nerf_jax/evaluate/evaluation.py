"""Scoring a trained model on the test views: PSNR, SSIM, LPIPS and, where the data has them,
geometry scores (depth error, floaters); the evaluator used while training, by render.py and by
the benchmark.
"""

import dataclasses
import json
import os

import imageio.v2 as imageio
import jax
import jax.numpy as jnp
import numpy as np
import optax

from nerf_jax.cameras import pose_refinement
from nerf_jax.data import masks as masks_lib
from nerf_jax.evaluate import lpips, metrics, visuals
from nerf_jax.render import background, image_renderer, renderer

# What metrics.json says about how held-out views were rendered (see `protocols`).
APPEARANCE_PROTOCOLS = {
    "mean": "mean code: the mean of the training images' appearance codes",
    "left_half": ("left half: a code fitted to each test image's left half (the field frozen), "
                  "every score over its right half (NeRF-W)")}
NO_CODE_HALF = ("right half: no appearance codes to fit, every score over each test image's "
                "right half (to compare with left_half runs)")
# What metrics.json says (its "masks") when the test views have masks (Dataset.masks).
MASK_RULE = ("masked pixels not scored: PSNR over the kept pixels, SSIM the mean of its map over "
             "windows centred on kept pixels, LPIPS the masked mean of its distance map")
POSE_PROTOCOL = ("similarity: the given test poses moved by the similarity (Umeyama) that takes "
                 "the given training cameras (centres and axes) to the refined ones")


@dataclasses.dataclass(frozen=True)
class Settings:
  """config.eval: the held-out views' appearance codes. The fit's defaults are nerfbaselines'
  "nerfw" protocol as NeRF-W runs it (Adam on the left half, the field frozen)."""
  appearance: str = "mean"  # held-out codes: 'mean' (training codes' mean), 'left_half' (NeRF-W)
  fit_steps: int = 1000  # left_half: Adam steps fitting each test image's code on its left half
  fit_rays: int = 1024  # left_half: rays drawn (with replacement) from the left half each step
  fit_lr: float = 1e-2  # left_half: Adam's first step size for the code
  fit_decay_every: int = 333  # left_half: the step size x0.1 every this many steps (0 = constant)
  test_every: int = 1  # score views 0, N, 2N, ... of each scale (1 = all): a shorter evaluation


@dataclasses.dataclass(frozen=True)
class EvalSettings:
  """How the test views are rendered and scored (run/builders.eval_settings builds them)."""
  background: tuple  # (r, g, b) in [0, 1]: the colour rendered and scored on (data.background)
  held_out: Settings  # the held-out views' codes (config.eval)
  photo_bounds: bool  # each view's rays within its own near/far (data.photo_bounds)


def make_evaluator(exp, settings):
  """fn(variables, max_views=None, out_dir=None, on_view=None) -> {'psnr', 'ssim', 'lpips',
  'per_view'} (variables: a TrainState's, renderer.py); without LPIPS (the `lpips` extra missing, or
  images under 31 px a side) the 'lpips' keys are absent and 'lpips_skipped' says why in one line.
  Where the data has true opacity (and depth) the view means of `geometry_errors` come too:
  'empty_opacity', 'floaters' (and 'depth_error').

  With appearance codes or refined poses the result also holds the protocol used for the test
  views (`protocols`) and, where the data knows the true poses, `pose_scores`.

  Evaluates the test views of `exp` (an experiment_parts.Experiment) as `settings`
  (EvalSettings) say: views 0, N, 2N, ... with eval.test_every = N, of each scale where the
  views have scale labels (`scored_views`; max_views
  takes the first of those). With `out_dir`, writes per view a PNG of [prediction | depth | ground
  truth] and depth `.npy`. on_view(index, out, truth) is called for every view with the
  rendered numpy dict (rgb [H, W, 3], depth [H, W], acc [H, W]) and the true image float32
  [H, W, 3] on settings.background (see `background.images_on_background`; the trainer sends
  the first one to TensorBoard).

  Every test view is rendered through its own camera (`Dataset.cameras`); where the test data
  has scale labels (`Dataset.labels`, mip-NeRF's multiscale data) the result also holds
  `scores_by_scale`'s 'by_scale' and 'mean_over_scales', and each per_view entry its 'label'.

  Where the test views have masks (`Dataset.masks`) no masked pixel is scored (MASK_RULE, the
  metrics' mask argument; left_half fits the codes on kept pixels alone) and the result holds
  'masks' (MASK_RULE) and 'masked_pixels', the share of the scored pixels that were masked; a
  view whose windows are all centred on masked pixels has no 'ssim'. A view whose left half
  keeps no pixel has nothing to fit a code on: the training codes' mean renders it, its
  per_view entry says 'mean_code': True, and one line says so.
  """
  every = settings.held_out.test_every
  if int(every) != every or every < 1:
    raise ValueError(f"config.eval.test_every={every!r}: use an integer >= 1 (1 = every view)")
  make_draw = image_renderer.make_image_renderer(exp.renderer, exp.image)
  bg = np.asarray(settings.background, np.float32)
  protocol = settings.held_out.appearance
  test_ds = exp.test_ds
  shared = (test_ds.height, test_ds.width, test_ds.intrinsics)
  camera = lambda i: shared if test_ds.image_cameras is None else test_ds.cameras.camera(i)
  if settings.photo_bounds and test_ds.bounds is None:
    raise ValueError("config.data.photo_bounds: the test views have no per-view bounds")
  truths = background.images_on_background(test_ds, bg)[1]
  half = appearance_protocol(protocol, exp.renderer.field.uses_images) == "left_half"
  scored = right_half if protocol == "left_half" else (lambda a: a)
  fit_code = make_code_fitter(exp.renderer, settings.held_out) if half else None
  lpips_reasons = {}  # (height, scored width) -> lpips.unavailable_reason

  def lpips_reason(truth):
    size = (truth.shape[0], scored(truth).shape[1])
    if size not in lpips_reasons:
      lpips_reasons[size] = lpips.unavailable_reason(*size)
    return lpips_reasons[size]

  def evaluate(variables, max_views=None, out_dir=None, on_view=None):
    views = scored_views(len(test_ds), every, max_views, test_ds.labels)
    per_view, lpips_skipped = [], None
    draw = make_draw(variables)
    poses = held_out_poses(exp, variables)
    for i in views:
      rays = exp.rays(poses[i], camera(i))
      if settings.photo_bounds:  # this view's own near and far (data.photo_bounds)
        rays = rays.replace(near=jnp.full_like(rays.near, test_ds.bounds[i][0]),
                            far=jnp.full_like(rays.far, test_ds.bounds[i][1]))
      truth, mask = truths[i], test_ds.mask(i)
      mean_code = False  # the training codes' mean in place of a fit on no pixel
      if fit_code is not None:  # this view's own code, from its left half
        weight = None if mask is None else jnp.asarray(left_half_mask(mask))
        mean_code = weight is not None and not bool(jnp.any(weight > 0))
        if mean_code:
          print(f"eval: view {i} keeps no pixel of its left half (its mask): the training "
                "codes' mean renders it, not a code fitted there", flush=True)
        draw = make_draw(variables if mean_code else fit_code(
            variables, *left_half(rays, truth), jnp.asarray(bg, jnp.float32), weight))
      out = draw(rays, bg)
      kept = None if mask is None else scored(mask)
      view = {"view": i, "psnr": float(metrics.psnr(scored(out["rgb"]), scored(truth), kept)),
              **geometry_errors(out, test_ds, i)}
      if mean_code:
        view["mean_code"] = True
      ssim = float(metrics.ssim(scored(out["rgb"]), scored(truth), kept))
      if np.isfinite(ssim):  # NaN: every window centred on a masked pixel
        view["ssim"] = ssim
      skipped = lpips_reason(truth)
      if skipped is None:
        view["lpips"] = float(lpips.lpips(scored(out["rgb"]), scored(truth), kept))
      lpips_skipped = lpips_skipped or skipped
      if test_ds.labels is not None:
        view["label"] = str(test_ds.labels[i])
      per_view.append(view)
      if on_view is not None:
        on_view(i, out, truth)
      if out_dir:
        _write_eval_view(out_dir, i, out, truth, exp.near, exp.far)
    names = dict.fromkeys(name for v in per_view for name in v
                          if name not in ("view", "label", "mean_code"))
    result = {name: float(np.mean([v[name] for v in per_view if name in v])) for name in names}
    if lpips_skipped is not None:
      result["lpips_skipped"] = lpips_skipped
    if test_ds.labels is not None:
      result.update(scores_by_scale(per_view))
    if test_ds.masks is not None:
      result.setdefault("ssim", float("nan"))  # no view had a kept window centre
      result["masks"] = MASK_RULE
      result["masked_pixels"] = 1.0 - masks_lib.kept_share(
          [scored(test_ds.mask(i)) for i in views])
    result.update(protocols(exp, variables, protocol))
    result.update(pose_scores(exp, variables))
    result["per_view"] = per_view
    if out_dir:
      with open(os.path.join(out_dir, "metrics.json"), "w") as f:
        json.dump(result, f, indent=2)
    return result

  return evaluate


def scored_views(num_views, every=1, max_views=None, labels=None):
  """The test views an evaluation scores: list of int, 0, every, 2 every, ... below num_views,
  the first max_views of them (None = all). labels: None, or each view's scale label
  (Dataset.labels, [num_views]): then every `every`-th view of each label, in view order, so
  that every scale keeps its share (mip-NeRF's multiscale views cycle through the scales: a
  plain stride of 4 would keep one scale of four)."""
  if labels is None:
    views = list(range(0, num_views, int(every)))
  else:
    seen = {}
    views = []
    for i in range(num_views):
      rank = seen[str(labels[i])] = seen.get(str(labels[i]), -1) + 1
      if rank % int(every) == 0:
        views.append(i)
  return views if max_views is None else views[:max_views]


SCALE_SCORES = ("psnr", "ssim", "lpips")  # what by_scale gives per label


def scores_by_scale(per_view):
  """{'by_scale': {label: {psnr, ssim, lpips, views}}, 'mean_over_scales': {psnr, ssim, lpips}}
  of per-view scores (dicts with 'label' and the SCALE_SCORES they have): each label's view
  mean, and the mean of the labels' means (every scale counts equally, as in mip-NeRF's
  multiscale tables); a score no view of a label has is left out of that label."""
  by_scale = {}
  for label in dict.fromkeys(v["label"] for v in per_view):
    views = [v for v in per_view if v["label"] == label]
    scores = {name: float(np.mean([v[name] for v in views]))
              for name in SCALE_SCORES if all(name in v for v in views)}
    by_scale[label] = {**scores, "views": len(views)}
  means = {name: float(np.mean([s[name] for s in by_scale.values()]))
           for name in SCALE_SCORES if all(name in s for s in by_scale.values())}
  return {"by_scale": by_scale, "mean_over_scales": means}


def left_half(rays, truth):
  """(rays [P], target float32 [P, 3]): the pixels of the left half (columns < W // 2) of a
  view's rays (Rays [H, W]) and its true image `truth` (float32 [H, W, 3]), flattened; what
  left_half fits the code on."""
  cut = truth.shape[1] // 2
  left = jax.tree_util.tree_map(lambda a: a[:, :cut].reshape(-1, *a.shape[2:]), rays)
  return left, jnp.asarray(truth[:, :cut].reshape(-1, 3), jnp.float32)


def left_half_mask(mask):
  """float32 [P]: the pixels' mask (float32 [H, W]) of the left half, flattened as left_half's."""
  return mask[:, :mask.shape[1] // 2].reshape(-1)


def right_half(image):
  """float [H, W - W // 2, ...]: the columns of `image` (float [H, W, ...]) that left_half
  scores, those it did not fit on."""
  return image[:, image.shape[1] // 2:]


def appearance_protocol(protocol, uses_images):
  """`protocol` (eval.appearance) where the field has appearance codes (`uses_images`), else
  None; ValueError naming the field for an unknown protocol."""
  if protocol not in APPEARANCE_PROTOCOLS:
    raise ValueError(f"config.eval.appearance={protocol!r}: use "
                     f"{' or '.join(map(repr, APPEARANCE_PROTOCOLS))}")
  return protocol if uses_images else None


def with_codes(variables, codes):
  """`variables` with every row of each network's appearance table set to its code in `codes`
  ({network: float32 [D]}): rendered without an image index (the mean code), it shows `codes`."""
  params = dict(variables["params"])
  for name, code in codes.items():
    table = params[name]["appearance"]
    params[name] = {**params[name], "appearance": jnp.broadcast_to(code, table.shape)}
  return {**variables, "params": params}


def make_code_fitter(ray_renderer, settings):
  """fn(variables, rays: Rays [P], target float32 [P, 3], background float32 [3], weight=None)
  -> variables showing the codes (one per network) fitted to `target` from the training codes'
  mean by least squares: settings.fit_steps Adam steps (settings: Settings) of step size fit_lr,
  times 0.1 after every fit_decay_every steps (`fit_schedule`), on fit_rays rays drawn from the
  P each step, the field frozen (NeRF-W's protocol for held-out views as nerfbaselines runs it;
  jitted once for every view of one size). weight: float32 [P] or None, each pixel's
  mask (0: never fitted on, nor drawn), keeping at least one pixel (the evaluator renders a view
  whose left half keeps none with the mean code). `ray_renderer` needs `render(variables, rays,
  background=)` returning {'coarse': {'rgb'}, ...} (RayRenderer's)."""
  tx = optax.adam(fit_schedule(settings))

  @jax.jit
  def fit(variables, rays, target, bg, weight=None):
    codes = {name: jnp.mean(p["appearance"], axis=0)
             for name, p in variables["params"].items() if isinstance(p, dict) and
             "appearance" in p}

    def loss(codes, key):
      if weight is None:
        pick = jax.random.randint(key, (settings.fit_rays,), 0, target.shape[0])
      else:  # kept pixels alone: drawn with probability proportional to their weight
        pick = jax.random.choice(key, target.shape[0], (settings.fit_rays,),
                                 p=weight / jnp.sum(weight))
      batch = jax.tree_util.tree_map(lambda a: a[pick], rays)
      out = renderer.final(ray_renderer.render(with_codes(variables, codes), batch,
                                               background=bg))
      return jnp.mean((out["rgb"] - target[pick]) ** 2)

    def step(carry, key):
      codes, opt = carry
      updates, opt = tx.update(jax.grad(loss)(codes, key), opt)
      return (optax.apply_updates(codes, updates), opt), None

    keys = jax.random.split(jax.random.PRNGKey(0), settings.fit_steps)
    (codes, _), _ = jax.lax.scan(step, (codes, tx.init(codes)), keys)
    return with_codes(variables, codes)
  return fit


def fit_schedule(settings):
  """The fit's step size (an optax schedule, or a float where it is constant): fit_lr, times
  0.1 after every fit_decay_every steps (nerfbaselines' 1000 steps, x0.1 every 333)."""
  if settings.fit_decay_every <= 0:
    return settings.fit_lr
  return optax.exponential_decay(settings.fit_lr, settings.fit_decay_every, 0.1, staircase=True)


def refined_poses(exp, variables):
  """The training cameras float32 [N, 4, 4] as refined (train.pose_refinement: params['poses']
  holds their corrections), or None without refinement."""
  corrections = variables["params"].get("poses")
  if corrections is None:
    return None
  return np.asarray(pose_refinement.corrected(exp.train_ds.poses, corrections))


def held_out_poses(exp, variables):
  """The test views' cameras float32 [T, 4, 4] in the frame the field was learnt in: as given,
  or with refined training cameras moved by POSE_PROTOCOL's similarity. Their intrinsics are
  always the stored ones: train.intrinsics_refinement's focal scales and lens
  (params['intrinsics']) belong to the training photos, and a held-out view is rendered
  through the pinhole its file stores (on `landmark`, exactly the camera that took it)."""
  refined = refined_poses(exp, variables)
  if refined is None:
    return exp.test_ds.poses
  similarity = pose_refinement.align_cameras(exp.train_ds.poses, refined)
  return pose_refinement.transform(exp.test_ds.poses, similarity)


def protocols(exp, variables, protocol):
  """{'appearance': ..., 'held_out_poses': ...}: how the test views were rendered and scored
  under the appearance protocol `protocol` (EvalSettings'), for the models or protocols that
  need saying (appearance codes or left_half, refined poses); {} otherwise."""
  out = {}
  if exp.renderer.field.uses_images:
    out["appearance"] = APPEARANCE_PROTOCOLS[appearance_protocol(protocol, True)]
  elif protocol == "left_half":
    out["appearance"] = NO_CODE_HALF
  if refined_poses(exp, variables) is not None:
    out["held_out_poses"] = POSE_PROTOCOL
  return out


def pose_scores(exp, variables):
  """Where the training data knows its true poses (`Dataset.true_poses`, a simulated pose
  error): how far the given and the refined training cameras are from them, aligned
  (pose_refinement.pose_errors): pose_error_given_degrees, pose_error_given_translation and,
  with refinement, pose_error_degrees, pose_error_translation; where the data has true depth
  and opacity, pose_error_given_reprojection_px and pose_error_reprojection_px. {} otherwise."""
  true = exp.train_ds.true_poses
  if true is None:
    return {}
  ds = exp.train_ds
  surface = None if ds.depths is None or ds.accs is None else (ds.depths, ds.accs,
                                                                 ds.intrinsics)
  scores = {f"pose_error_given_{k}": v
            for k, v in pose_refinement.pose_errors(ds.poses, true, surface).items()}
  refined = refined_poses(exp, variables)
  if refined is not None:
    scores.update({f"pose_error_{k}": v
                   for k, v in pose_refinement.pose_errors(refined, true, surface).items()})
  return scores


OPAQUE, EMPTY = 0.99, 0.01  # true opacity of pixels scored for depth, and of empty pixels


FLOATER_ACC = 0.1  # rendered opacity from which an empty pixel counts as showing a floater


GEOMETRY_SCORES = ("depth_error", "empty_opacity", "floaters")  # what geometry_errors gives


def geometry_errors(out, dataset, index):
  """Geometry scores of one rendered view where the data has them, {} otherwise.

  depth_error: median |depth - true depth| over pixels the truth covers (opacity > OPAQUE), in
  scene units (needs `dataset.depths`). empty_opacity: the mean rendered opacity over pixels
  the truth leaves empty (opacity < EMPTY); floaters: the fraction of those that render with
  opacity > FLOATER_ACC (need `dataset.accs`). Masked pixels (dataset.masks) are left out.
  out: the render's numpy dict (depth, acc [H, W]).
  """
  scores = {}
  if dataset.accs is None:
    return scores
  true_acc = dataset.accs[index]
  kept = np.ones(true_acc.shape, bool) if dataset.masks is None else dataset.mask(index) > 0
  empty = (true_acc < EMPTY) & kept
  if np.any(empty):
    scores["empty_opacity"] = float(np.mean(out["acc"][empty]))
    scores["floaters"] = float(np.mean(out["acc"][empty] > FLOATER_ACC))
  opaque = (true_acc > OPAQUE) & kept
  if dataset.depths is not None and np.any(opaque):
    scores["depth_error"] = float(np.median(np.abs(out["depth"] - dataset.depths[index])[opaque]))
  return scores


def _write_eval_view(out_dir, index, out, truth, near, far):
  os.makedirs(out_dir, exist_ok=True)
  panel = np.concatenate([visuals.to_uint8(out["rgb"]), visuals.colorize(out["depth"], near, far),
                          visuals.to_uint8(truth)], axis=1)
  imageio.imwrite(os.path.join(out_dir, f"view_{index:03d}.png"), panel)
  np.save(os.path.join(out_dir, f"depth_{index:03d}.npy"), out["depth"].astype(np.float32))
