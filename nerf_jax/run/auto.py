"""`--config=auto`: a config decided from the training views (characterise.py's rules) and the
user's flags, which win over the decisions.
"""

import jax
import ml_collections
import numpy as np

from nerf_jax.run import (characterise, config_lib, from_data, subject, transient_share,
                          warm_up)

APPEARANCE_DIMS = 8  # the appearance codes' length auto switches on (NeRF-W: 48, nerfacto: 32)
CONTRACTION = "linf"  # where the rays leave the box: nerfacto's contraction (docs/real_captures.md)
# auto: object captures from this many pixels a side use configs/detail.py, smaller ones fast.py.
# detail.py won at the smallest size measured, the built-in scenes' 100 px (docs/regret.md: 300 s
# on one core, diffuse +4.25 dB; 60 s, exposure +7.10, crowd +3.21); below it, unmeasured.
LARGE_IMAGES = 100
# Zip-NeRF's multisampling with its level weights, or the weights alone (multisample False):
# on the multiscale lego at 10 CPU-minutes the weights alone score best (docs/multiscale.md).
ANTIALIAS_MULTISAMPLE = False
# Transients (passers-by): RobustNeRF's loss above this share of clustered outliers after the
# warm-up; crowd 0.027, the clean built-in scenes <= 0.0033 at 48 px (docs/photo_collections.md).
TRANSIENT_SHARE = 0.01
# A photo collection's subject fills the inner region (data.subject) when the masks or the
# sparse points mark a subject whose largest half-extent is under this share of the cameras'
# median distance from it (landmark: 0.5 of ~4.2; crowd's masks mark passers-by, no subject).
SUBJECT_SHARE = 0.25
# Effects that pay only after enough steps: {field auto turns on: (its value off, the fewest steps
# from which it pays)}. Auto leaves one off where the run's step budget holds fewer: the steps
# given, or those a time budget holds with the waiting effects off (by_steps, decided once the
# run knows them). Measured with detail.py on one core, side by side (docs/regret.md, the step
# rule), in the steps of the run with the effect off: view dependence on glossy loses 4.2 dB at
# 85 steps and 1.3 at 124, gains 0.5 at 180; the trimmed loss on crowd (its patch batches)
# loses 1.5 dB at 69 steps and gains 1.9 at 99. The thresholds: where the lines between cross.
MIN_STEPS = {"model.view_dependent": (False, 165), "loss.robust.weight": (0.0, 80)}
# Depth from the sparse points' tracks (DS-NeRF's loss, config.loss.depth): on with this weight
# where the training views have tracks (a COLMAP model), number at most DEPTH_MAX_VIEWS and the
# samples lie where the points are: forward-facing (NDC) or a subject the masks mark (photo
# bounds). Measured side by side at equal steps (docs/photo_collections.md, depth from the
# tracks): fern (17 views, llff.py, 1000 steps) +0.68 dB; landmark_sfm (masks, 600 steps)
# +1.04 dB; Sacre-Coeur (16 photos, unbounded, no masks, 600 steps) -0.4 to -1.2 dB (LPIPS
# better): off there. More views than measured: off, unmeasured.
DEPTH_WEIGHT = 0.1
DEPTH_MAX_VIEWS = 100
# Cameras that disagree with their points: where one camera is stored for every photo and the
# sparse points' mean reprojection error exceeds this share of the image diagonal, each photo's
# focal and pose are refined with the field (train.intrinsics_refinement, train.pose_refinement)
# in place of the zooms fitted to the masks. landmark_sfm (one focal for a 3x zoom spread): 3.2%
# (4.5 px at 100 px); COLMAP models of real photos: 0.03-0.05% (fern 1.32 px at 4032 px,
# Sacre-Coeur 0.57 px at ~1080 px; at most 4x more against images read at data.factor). On
# landmark_sfm at 600 steps refinement gained 0.59 dB over the fitted zooms without the depth,
# 0.89 with it (docs/photo_collections.md, the levers on the twin).
CAMERA_ERROR_SHARE = 0.005
_OWN = ("auto", "auto_decisions", "auto_flags", "auto_by_steps")  # auto's own fields
# On a GPU backend, the config that takes each CPU choice's place: the configs/gpu/ one where it
# won on an H200 (docs/gpu.md, 2026-11-28: gpu/lego 32.63 dB on lego in 60 s against detail.py's
# 30.45 in 120 s; gpu/llff 23.85 on fern against llff.py's 23.34), the CPU's own where it lost
# (gpu/capture 19.57 dB on fox in 60 s against capture.py's 27.36).
GPU_CONFIGS = {"fast": "gpu/lego", "detail": "gpu/lego", "llff": "gpu/llff",
               "capture": "capture"}


def for_backend(chosen, backend):
  """(config name, one line saying why) of the CPU choice `chosen` ('fast', 'detail', 'llff',
  'capture') on `backend` (jax.default_backend(): 'cpu', 'gpu', ...): a GPU's config of
  GPU_CONFIGS on 'gpu', else `chosen` itself, as measured on a CPU."""
  if backend != "gpu":
    return chosen, (f"backend {backend}: configs/{chosen}.py, the configs measured on a CPU "
                    "(a GPU backend takes configs/gpu/)")
  gpu = GPU_CONFIGS[chosen]
  if gpu == chosen:
    return gpu, (f"backend gpu: configs/{gpu}.py, as on a CPU: it beat configs/gpu/'s "
                 "config of its kind on an H200 (docs/gpu.md)")
  return gpu, (f"backend gpu: configs/{gpu}.py, sized for a GPU (measured on an H200: "
               f"docs/gpu.md), in place of the CPU's configs/{chosen}.py")


def cone_effects(config):
  """{field: value} that make the representation `config` read cones (docs/multiscale.md): the
  integrated positional encoding for 'posenc', Zip-NeRF's anti-aliasing for a lattice (its
  multisampling as ANTIALIAS_MULTISAMPLE says). Rendering keeps the representation's marching,
  which queries each sample's frustum as the plain path does. {} for an encoding without cones
  (TensoRF)."""
  encoding = config.model.encoding
  if encoding == "posenc":
    return {"model.encoding": "ipe"}
  if encoding in ("grid", "hash"):
    return {f"model.{encoding}.antialias": True,
            f"model.{encoding}.multisample": ANTIALIAS_MULTISAMPLE}
  return {}


def transient_effects(dataset, collection, patch_size):
  """({field: value}, one line): RobustNeRF's trimmed loss (its switch, loss.robust.weight: the
  patch batches follow from it) when a warm-up on the photos of `dataset` (one camera) leaves
  more than TRANSIENT_SHARE of their pixels clustered outliers that some photos hold
  (transient_share.transient_share: passers-by). The patches are patch_size a side (the run's
  train.patch_size), train.patch_size set smaller only for photos smaller than that. Measured
  only for a photo collection (`collection`: the photos have their own looks, the appearance
  rule), as the warm-up costs half a minute on a CPU."""
  if not collection:
    return {}, ("no transients: not measured (the photos share one look: not a collection "
                "taken by many)")
  share = transient_share.transient_share(*warm_up.photos_and_renders(dataset))[0]
  reason = (f"{100 * share:.1f}% of the training pixels are clustered outliers specific to "
            f"some photos after a {warm_up.WARM_UP_STEPS}-step warm-up "
            f"({'>' if share > TRANSIENT_SHARE else '<='} {100 * TRANSIENT_SHARE:g}%)")
  if share <= TRANSIENT_SHARE:
    return {}, f"no transients: {reason}"
  effects = {"loss.robust.weight": 1.0}
  patch = int(min(patch_size, dataset.height, dataset.width))
  if patch < patch_size:  # a patch lies in one photo
    effects["train.patch_size"] = patch
  return (effects,
          f"transients left out: RobustNeRF's trimmed loss on {patch} x {patch} patches "
          f"(loss.robust): {reason}")


def depth_effects(dataset, placed):
  """({field: value}, [line]): DS-NeRF's depth from the sparse points' tracks
  (loss.depth.weight=DEPTH_WEIGHT) where the training views `dataset` carry tracks
  (Dataset.observations), number at most DEPTH_MAX_VIEWS (the fog of few views: DS-NeRF) and
  the samples lie where the points are (`placed`: '' if not, else a phrase saying how: NDC
  rays, or the masked subject's photo bounds); ({}, []) without tracks, so the data of every
  other format prints nothing more."""
  if dataset.observations is None or not len(dataset.observations):
    return {}, []
  views, seen = len(dataset), len(dataset.observations)
  points = len(set(dataset.observations[:, 1].tolist()))
  measured = (f"{seen} keypoints of {points} sparse points in {views} training views "
              f"({'<=' if views <= DEPTH_MAX_VIEWS else '>'} {DEPTH_MAX_VIEWS})")
  if views > DEPTH_MAX_VIEWS:
    return {}, [f"no depth from the tracks (loss.depth off: more views than measured): "
                f"{measured}"]
  if not placed:
    return {}, [f"no depth from the tracks (loss.depth off: an unbounded capture without a "
                f"subject's masks, where it lost on Sacre-Coeur): {measured}"]
  return ({"loss.depth.weight": DEPTH_WEIGHT},
          [f"depth from the sparse points' tracks (DS-NeRF, loss.depth.weight="
           f"{DEPTH_WEIGHT:g}; {placed}): {measured}"])


def camera_effects(dataset, stored_camera, fitted_zooms):
  """({field: value}, line or None): each photo's focal and pose refined with the field in place
  of the zooms fitted to the masks (`fitted_zooms`: the subject rule turned data.photo_zoom on)
  where one camera is stored for every photo (`stored_camera`) and the sparse points' mean
  reprojection error (Dataset.point_errors, pixels) exceeds CAMERA_ERROR_SHARE of the image
  diagonal: the stored camera disagrees with what the photos saw. None where not measured (no
  tracks, a camera per photo, or no fitted zooms): the caller's line stands."""
  errors = dataset.point_errors
  if not (stored_camera and fitted_zooms) or errors is None or not len(errors):
    return {}, None
  share = float(np.nanmean(errors)) / float(np.hypot(dataset.height, dataset.width))
  measured = (f"the sparse points' mean reprojection error is {100 * share:.2g}% of the image "
              f"diagonal ({'>' if share > CAMERA_ERROR_SHARE else '<='} "
              f"{100 * CAMERA_ERROR_SHARE:g}%)")
  if share <= CAMERA_ERROR_SHARE:
    return {}, f"pose refinement: off (the stored camera fits its points: {measured})"
  return ({"data.photo_zoom": False, "train.intrinsics_refinement": True,
           "train.pose_refinement": True},
          f"cameras refined with the field (train.intrinsics_refinement, "
          f"train.pose_refinement; in place of data.photo_zoom): the one stored camera "
          f"disagrees with the photos: {measured}")


def subject_effects(dataset, collection, contraction="", stored_camera=True):
  """({field: value}, [line]): for a photo collection (`collection`), data.subject='auto' where
  the masks or the sparse points of `dataset` (the training photos, each through its own camera:
  a resampled view would crop them) mark a subject (subject.subject_box)
  whose largest half-extent is under SUBJECT_SHARE of the cameras' median distance from its
  centre, and the space beyond the inner region contracted (CONTRACTION) unless `contraction`
  (the run's) already is: the cameras and the rest of the world lie outside it; where the
  masks mark it (only its pixels train), each photo sampled within its depths (data.photo_bounds:
  no sample between a camera and the subject to hold a cloud that explains one photo) and no
  density in the space around it that the masks' vote rules out (data.visual_hull: a halo there
  explains some photos and spoils the rest) and, where the data stores one camera for every
  photo (`stored_camera`), each photo's focal fitted to its mask (data.photo_zoom); else ({}, []
  where not a collection, or the line saying why the world stays)."""
  if not collection:
    return {}, []
  box = subject.subject_box(dataset)
  distance = float(np.median(np.linalg.norm(dataset.poses[:, :3, 3] - box.centre, axis=1)))
  half = float(np.max(box.half))
  if box.source not in ("points", "masks"):
    return {}, ["the world as it is (data.subject off): no sparse points or masks mark a "
                "subject (its box would be the cameras')"]
  measured = (f"the {box.source} mark a subject of half-extent {half:.3g}, the cameras "
              f"{distance:.3g} from it ({'<' if half < SUBJECT_SHARE * distance else '>='} "
              f"{SUBJECT_SHARE:g} of that)")
  if half >= SUBJECT_SHARE * distance:
    return {}, [f"the world as it is (data.subject off): {measured}"]
  effects = {"data.subject": "auto"}
  beyond = ""
  if not contraction:
    effects["data.contraction"] = CONTRACTION
    beyond = f", the space beyond contracted (data.contraction={CONTRACTION!r})"
  if box.source == "masks":  # only the subject's pixels train: nothing else on a ray is seen
    effects.update({"data.photo_bounds": True, "data.visual_hull": True})
    beyond += (", each photo sampled within the subject's depths from it "
               "(data.photo_bounds: its masks keep the subject alone), no density where the "
               "masks' vote rules it out (data.visual_hull: no pixel says that space is empty)")
    if stored_camera:  # one focal stored for photos taken at many zooms
      effects["data.photo_zoom"] = True
      beyond += (", each photo's focal fitted to its mask (data.photo_zoom: the data stores "
                 "one camera for every photo)")
  return effects, [f"the world scaled and moved so the subject fills the inner region "
                   f"(data.subject='auto'){beyond}: {measured}"]


def cone_summary(config):
  """One phrase naming what `cone_effects` switches on for `config`."""
  effects = cone_effects(config)
  if not effects:
    return f"but model.encoding={config.model.encoding!r} has no anti-aliased form yet"
  return ", ".join(f"{k}={v!r}" for k, v in effects.items())


def box_effects(result, dataset, user):
  """({field: value}, [lines]): the box of an unbounded capture. Where `result` (the chosen
  config) takes the box from the data without contracting, the share of training rays that
  leave that box (from_data.cut_share, the share the run's warning reads; on the user's
  data.scene_bound if `user`, {field: value} of their flags, sets one) decides: above
  from_data.CUT_SHARE the space beyond is contracted (data.contraction=CONTRACTION), so the
  warning never contradicts auto (a data.contraction in `user` is theirs: not measured). Where
  the space beyond is contracted and the cameras look at one point (characterise.focus), the
  world is centred there (data.focus), the inner region
  sized from the sparse points' box where the data has one, else from the cameras' distances
  (from_data.scene_box). `dataset`: the training views of one camera."""
  effects, lines = {}, []
  contraction = user.get("data.contraction", result.data.contraction)
  bound = user.get("data.scene_bound", result.data.scene_bound)
  if not contraction and "data.contraction" not in user and (bound == -1 or bound > 0):
    if bound == -1:
      bound, why = from_data.scene_box("", dataset)
    else:
      why = "data.scene_bound"
    near, far = (user.get(f"data.{k}", 0.0) or getattr(dataset, k) for k in ("near", "far"))
    pixel_center = user.get("data.pixel_center", -1.0)
    pixel_center = dataset.pixel_center if pixel_center == -1 else pixel_center
    share = from_data.cut_share(dataset, bound, near, far, pixel_center)
    if share is not None:
      cut = share > from_data.CUT_SHARE
      measured = (f"{100 * share:.0f}% of the training rays leave the box ±{bound:.3g} from "
                  f"{why} before their far bound {far:.3g} ({'>' if cut else '<='} "
                  f"{100 * from_data.CUT_SHARE:.0f}%)")
      if cut:
        contraction = effects["data.contraction"] = CONTRACTION
        lines.append(f"the space beyond the box contracted (data.contraction="
                     f"{CONTRACTION!r}): {measured}")
      else:
        lines.append(f"no contraction: {measured}")
  if contraction:
    focus = characterise.focus(dataset.poses)
    effects["data.focus"] = focus.found
    size = ("the sparse points' box (core)" if dataset.core is not None else
            "the cameras' distances from it")
    lines.append(f"the inner region centred where the cameras look (data.focus), sized from "
                 f"{size}: {focus.reason}" if focus.found else
                 f"the inner region centred on the data's origin: {focus.reason}")
  return effects, lines


def _flat(config):
  """{dotted name: value} of every leaf field of a ConfigDict."""
  out = {}
  def walk(node, prefix):
    for key, value in node.items():
      if isinstance(value, ml_collections.ConfigDict):
        walk(value, f"{prefix}{key}.")
      else:
        out[prefix + key] = tuple(value) if isinstance(value, list) else value
  walk(config, "")
  return out


def auto_config(config, dataset, backend=None, before_loading=({}, [])):
  """`config` (config.auto: configs/auto.py and the user's flags) decided from the training
  views `dataset` by characterise.decide: the representation of the config that suits the
  kind of capture (detail.py for an object on a background from LARGE_IMAGES pixels, fast.py
  below,
  configs/llff.py (grids in NDC) for a forward-facing one, capture.py otherwise or
  when there are too few cameras; on a 'gpu' `backend` (default jax.default_backend()) its
  configs/gpu/ counterpart, `for_backend`) and the effects it calls for (view dependence only
  where it is measured: the views need depth; else the representation's setting stands;
  appearance codes with held-out photos scored the NeRF-W way; an unbounded capture's box,
  contraction and centre: `box_effects`; a photo collection's subject filling the inner
  region: `subject_effects`). A field the user set (named in config.auto_flags by
  the command line, or differing from configs/auto.py's) wins over the decision, with one line
  saying so. Prints one line per
  decision with its reason, and one naming the backend and the config it chose; the lines go
  to config.auto_decisions (config.json), and auto is off in the result (a restored run keeps
  what was decided). before_loading: ({field: value}, [line]) decided before `dataset` was
  loaded (resolution.factor_effects: data.factor), recorded first."""
  base = _flat(config_lib.load("auto"))
  given = _flat(config)
  user = {k: v for k, v in given.items()
          if (base.get(k) != v or k in config.auto_flags) and k not in _OWN}
  stored_camera = dataset.image_cameras is None  # one camera stored for every photo
  tracked = dataset  # every training view with its tracks (the depth rule)
  decisions = characterise.decide(dataset)  # scales from every camera, the rest from image 0's
  photos, dataset = dataset, dataset.one_camera()  # the subject: each photo through its camera
  effects, lines = dict(before_loading[0]), list(before_loading[1])
  if decisions is None:
    chosen = "capture"
    lines.append(f"{len(dataset)} cameras are too few to characterise (< "
                 f"{characterise.MIN_CAMERAS}): using configs/capture.py's defaults")
  else:
    found = {d.name: d for d in decisions}
    if found["forward"].found:
      chosen = "llff"  # the winner on fern (docs/quality_per_second.md)
      effects.update({"data.ndc": True, "data.lindisp": False})
    elif found["background"].found:
      chosen = "detail" if max(dataset.height, dataset.width) >= LARGE_IMAGES else "fast"
      effects["train.random_background"] = True
    else:
      chosen = "capture"
  chosen, backend_line = for_backend(chosen, backend or jax.default_backend())
  result = config_lib.load(chosen)
  if decisions is not None and found["scales"].found:
    effects.update(cone_effects(result))
  box_lines = []
  if decisions is not None and found["unbounded"].found:
    box, box_lines = box_effects(result, dataset, user)
    effects.update(box)
  if decisions is not None:
    bg = tuple(float(c) for c in dataset.background)
    effects["data.background"] = ("white" if bg == (1.0, 1.0, 1.0) else
                                  "black" if bg == (0.0, 0.0, 0.0) else bg)
    effects["model.appearance_dims"] = APPEARANCE_DIMS if found["appearance"].found else 0
    if found["appearance"].found:  # held-out photos scored as NeRF-W scores them
      effects["eval.appearance"] = "left_half"
    if found["view_dependence"].found is not None:  # else the representation's own setting
      effects["model.view_dependent"] = found["view_dependence"].found
    settings = {"background": "an object on a background: a box, random backgrounds while "
                              "training",
                "forward": "forward-facing: NDC rays (data.ndc)",
                "unbounded": "unbounded: the scene box from the data (data.scene_bound=-1)",
                "appearance": f"per-photo appearance codes (model.appearance_dims="
                              f"{APPEARANCE_DIMS}), held-out photos scored with a code fitted "
                              "on their left half (eval.appearance='left_half')",
                "view_dependence": "view dependence: colour from the viewing direction too "
                                   "(model.view_dependent)",
                "scales": "cameras at several scales: cones, " + cone_summary(result)}
    for d in decisions:
      if d.found is None:  # the representation's own setting
        lines.append(f"view dependence {'on' if result.model.view_dependent else 'off'} as "
                     f"in configs/{chosen}.py: {d.reason}")
      else:
        absent = "one scale" if d.name == "scales" else "no " + d.name.replace("_", " ")
        lines.append(f"{settings[d.name] if d.found else absent}: {d.reason}")
    lines += box_lines
    fill, fill_lines = subject_effects(
        photos, found["appearance"].found,
        user.get("data.contraction", effects.get("data.contraction", result.data.contraction)),
        stored_camera)
    effects.update(fill)
    lines += fill_lines
    transient, transient_line = transient_effects(
        dataset, found["appearance"].found,
        user.get("train.patch_size", result.train.patch_size))
    effects.update(transient)
    lines.append(transient_line)
    placed = ("forward-facing: NDC rays" if found["forward"].found else
              "the masked subject's photo bounds" if fill.get("data.photo_bounds") else "")
    depth, depth_lines = depth_effects(tracked, placed)
    effects.update(depth)
    lines += depth_lines
    cameras, camera_line = camera_effects(tracked, stored_camera,
                                          bool(fill.get("data.photo_zoom")))
    effects.update(cameras)
    if camera_line:
      lines.append(camera_line)
    else:
      lines.append("pose refinement: off (nothing in the photos measures a pose error; "
                   "train.pose_refinement=True switches it on)")
  pending = tuple(f for f, (off, _) in MIN_STEPS.items()
                  if f in effects and f not in user and effects[f] != off)
  if pending:
    lines.append(f"step rule: {', '.join(pending)} kept only where the run's step budget "
                 "holds the steps from which they pay (auto.MIN_STEPS), decided once the "
                 "budget is known")
  lines.append(backend_line)
  lines.append(f"representation: configs/{chosen}.py")
  values = {**_flat(result), **effects}
  for name, value in user.items():
    if name in effects and effects[name] != value:
      lines.append(f"{name}={value!r} from your flags, not auto's {effects[name]!r}")
    values[name] = value
  for name, value in values.items():
    if name not in _OWN:
      config_lib.set_field(result, name, value)
  result.auto = False
  result.auto_by_steps = pending
  result.auto_decisions = tuple(lines)
  for line in lines:
    print(f"auto: {line}", flush=True)
  return result


def by_steps(config, steps):
  """(config, [line]): a copy of `config` with each effect of config.auto_by_steps that pays
  only from more than `steps` steps (MIN_STEPS) off, one line each, and the record cleared
  (decided: config.json keeps the result); `config` itself and [] where nothing is pending.
  steps: int, the run's step budget (given, or fitted to its time budget)."""
  if not config.auto_by_steps:
    return config, []
  out, lines = ml_collections.ConfigDict(config.to_dict()), []
  for name in config.auto_by_steps:
    off, fewest = MIN_STEPS[name]
    keep = steps >= fewest
    if not keep:
      config_lib.set_field(out, name, off)
    lines.append(f"step rule: {name}={config_lib.get_field(out, name)!r}, the run's budget "
                 f"holds {steps} steps ({'>=' if keep else '<'} the {fewest} from which it "
                 "pays)")
  out.auto_by_steps = ()
  out.auto_decisions = (*config.auto_decisions, *lines)
  return out, lines

