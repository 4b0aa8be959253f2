"""A photo collection's subject fills the inner region (data.subject), where masks or sparse
points mark one (subject.subject_box)."""

import numpy as np

from nerf_jax.cameras.scene_settings import SceneSettings
from nerf_jax.run import config_lib, subject
from nerf_jax.run.auto.rule import Rule, measured
from nerf_jax.run.auto.rules.contraction import CONTRACTION

# A photo collection's subject fills the inner region (data.subject) when the masks or the
# sparse points mark a subject whose largest half-extent is under this share of the cameras'
# median distance from it (landmark: 0.5 of ~4.2; crowd's masks mark passers-by, no subject).
SUBJECT_SHARE = 0.25


def subject_effects(dataset, collection, contraction=SceneSettings.contraction,
                    stored_camera=True):
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


@measured
def decide(context):
  """subject_effects of the photos (each through its own camera) of a collection (the
  appearance rule's), the run's contraction as decided so far or the user's."""
  return subject_effects(
      context.photos, context.found("appearance"),
      context.user.get("data.contraction", context.effects.get(
          "data.contraction", context.result.data.contraction)),
      context.photos.image_cameras is None)  # one camera stored for every photo


def flip_subject(result, base, context):
  if result.data.subject:
    return {"data.subject": "", "data.photo_bounds": False, "data.visual_hull": False,
            "data.photo_zoom": False}, ""
  return None, "no sparse points or masks marked a subject to fill the inner region"


def _flip_on_subject(field):
  """A flip of `field`, which auto decides only with a subject (data.subject)."""
  def flip(result, base, context):
    if not result.data.subject:
      return None, "decided only with a subject (data.subject)"
    return {field: not bool(config_lib.get_field(result, field))}, ""
  return flip


RULE = Rule("subject", decide, row="subject box",
            fields=("data.subject", "data.photo_bounds", "data.visual_hull", "data.photo_zoom"),
            flips={"subject": flip_subject,
                   **{name: _flip_on_subject(f"data.{name}")
                      for name in ("photo_bounds", "visual_hull", "photo_zoom")}})
