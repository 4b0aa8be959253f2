"""What a photographer's capture adds to the simulator's exact views: each photo's own exposure
and white balance, camera poses that structure from motion got slightly wrong, and passers-by
in some photos (occluders.py).

They apply to the training views of a built-in scene that declares them (`Effects.appearance`,
`Effects.pose_error`; data/loaders.py): the held-out views keep the neutral look (gain 1) and
their true poses, so a test score measures the model, not the test photo's own exposure or
pose error. `held_out_with_own_looks` gives the held-out views looks of their own instead, as a
real capture's (data.held_out_looks='own'), for NeRF-W's left-half protocol. The amounts are
known, so what a model recovers can be measured.
"""

import dataclasses

import numpy as np

from nerf_jax.data.scenes import landmark, landmark_sfm, occluders
from nerf_jax.data.scenes.scene import CAPTURE

# Each draw has a stream of its own: default_rng(seed) alone would repeat the stream the
# cameras were drawn from (scenes.random_poses), tying a photo's gain to where it stands.
GAIN_STREAM, POSE_STREAM = 0x6A1, 0x9053

EXPOSURE_STOPS = 0.6  # each photo's exposure: 2^u, u ~ U[-0.6, 0.6] stops
WHITE_BALANCE = 0.15  # each channel's gain: exp(w), w ~ U[-0.15, 0.15], times the exposure
POSE_DEGREES = 1.0  # each training camera turns by exactly this about a random axis ...
SCENE_SIZE = 2.4  # ... (the 360° scenes' content fits in a ball of radius 1.2) ...
POSE_TRANSLATION = 0.02 * SCENE_SIZE  # ... and moves by exactly 2% of the scene's size


def gains(num_views, seed=0):
  """Per-photo colour gains float32 [N, 3]: exposure times white balance (module constants)."""
  rng = np.random.default_rng([seed, GAIN_STREAM])
  stops = rng.uniform(-EXPOSURE_STOPS, EXPOSURE_STOPS, (num_views, 1))
  balance = rng.uniform(-WHITE_BALANCE, WHITE_BALANCE, (num_views, 3))
  return (2.0 ** stops * np.exp(balance)).astype(np.float32)


def with_gains(images, view_gains):
  """Photos float32 [N, H, W, 3] scaled by their gains float32 [N, 3], clipped to [0, 1] as a
  sensor saturates."""
  return np.clip(images * view_gains[:, None, None, :], 0.0, 1.0).astype(np.float32)


def rotation(axis_angle):
  """Rotation matrices float64 [..., 3, 3] of axis-angle vectors float [..., 3] (Rodrigues)."""
  w = np.asarray(axis_angle, np.float64)
  theta = np.linalg.norm(w, axis=-1)[..., None, None]
  k = w / np.maximum(np.linalg.norm(w, axis=-1, keepdims=True), 1e-300)
  zero = np.zeros_like(k[..., 0])
  big_k = np.stack([np.stack([zero, -k[..., 2], k[..., 1]], -1),
                    np.stack([k[..., 2], zero, -k[..., 0]], -1),
                    np.stack([-k[..., 1], k[..., 0], zero], -1)], -2)
  return np.eye(3) + np.sin(theta) * big_k + (1 - np.cos(theta)) * big_k @ big_k


def perturbed(poses, degrees=POSE_DEGREES, translation=POSE_TRANSLATION, seed=0):
  """Cameras float32 [N, 4, 4], each turned by exactly `degrees` about a random axis through
  its centre and moved by exactly `translation` (scene units) in a random direction."""
  rng = np.random.default_rng([seed, POSE_STREAM])
  unit = lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True)
  axes = unit(rng.normal(size=(len(poses), 3)))
  moves = unit(rng.normal(size=(len(poses), 3))) * translation
  out = np.array(poses, np.float64)
  out[:, :3, :3] = out[:, :3, :3] @ rotation(np.radians(degrees) * axes)
  out[:, :3, 3] += moves
  return out.astype(np.float32)


LENS_PARTS = ("zoom", "distortion")  # the parts of Effects.lens that data.without leaves out alone


def photographed(train, effects, seed=0, lens_parts=LENS_PARTS):
  """The training views `train` (a Dataset) as the capture declaring `effects` took them:
  each photo through its own zoom and lens (lens: the `landmark` scene's, re-rendered by
  landmark.py, passers-by included; only the LENS_PARTS in `lens_parts`), passers-by in front
  of the subject in some photos (transients, occluders.py), the poses a structure from motion
  with one shared focal solves from those photos (sfm_poses, landmark_sfm.py), per-photo gains
  over the whole photo (appearance), poses off by a known amount (pose_error). The true poses
  are kept in `Dataset.true_poses` where the stored ones differ."""
  zoom, distortion = ("zoom" in lens_parts, "distortion" in lens_parts)
  if effects.lens and lens_parts:
    train = landmark.photographed(train, effects.transients, seed, zoom, distortion)[0]
  elif effects.transients:
    train = occluders.with_crowd(train, seed=seed)[0]
  if effects.sfm_poses:
    lensed = bool(effects.lens and lens_parts)  # the lens the photos were taken through
    train = landmark_sfm.posed(train, seed, lensed and zoom, lensed and distortion)
  if effects.appearance:
    train = dataclasses.replace(train, images=with_gains(train.images, gains(len(train), seed)))
  if effects.pose_error:
    true = train.poses if train.true_poses is None else train.true_poses
    train = dataclasses.replace(train, poses=perturbed(train.poses, seed=seed), true_poses=true)
  return train


def without(effects, names):
  """(effects, lens_parts): the Effects `effects` less the capture effects named in `names`
  (data.without: comma-separated, from scene.CAPTURE and LENS_PARTS), and the parts of the
  lens kept. ValueError naming the field for a name that is neither."""
  names = {n.strip() for n in names.split(",") if n.strip()}
  valid = sorted(CAPTURE) + list(LENS_PARTS)
  unknown = sorted(names - set(valid))
  if unknown:
    raise ValueError(f"config.data.without: unknown {', '.join(unknown)} (valid: "
                     f"{', '.join(valid)})")
  effects = dataclasses.replace(effects, **{n: False for n in names & CAPTURE})
  return effects, tuple(p for p in LENS_PARTS if p not in names)


def held_out_with_own_looks(test, effects, num_train, seed=0):
  """The held-out views `test` (a Dataset) each with a look of its own, as a real capture's
  held-out photos have (what NeRF-W's left-half protocol is for), where `effects` declare
  per-photo looks: gains drawn after the `num_train` training photos' from the same stream."""
  if not effects.appearance:
    return test
  own = gains(num_train + len(test), seed)[num_train:]
  return dataclasses.replace(test, images=with_gains(test.images, own))
