"""Depth from the sparse points' tracks (DS-NeRF's loss, config.loss.depth) where the training
views carry tracks (a COLMAP model)."""

from nerf_jax.run.auto.rule import Rule, measured

# Depth from the sparse points' tracks (DS-NeRF's loss, config.loss.depth): on with this weight
# where the training views have tracks (a COLMAP model), number at most DEPTH_MAX_VIEWS and the
# samples lie where the points are: forward-facing (NDC) or a subject the masks mark (photo
# bounds). Measured side by side at equal steps (docs/photo_collections.md, depth from the
# tracks): fern (17 views, llff.py, 1000 steps) +0.68 dB; landmark_sfm (masks, 600 steps)
# +1.04 dB; Sacre-Coeur (16 photos, unbounded, no masks, 600 steps) -0.4 to -1.2 dB (LPIPS
# better): off there. More views than measured: off, unmeasured.
DEPTH_WEIGHT = 0.1
DEPTH_MAX_VIEWS = 100


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


@measured
def decide(context):
  """depth_effects of every training view (each through its own camera), the samples placed
  by NDC rays (the forward rule) or a masked subject's photo bounds (the subject rule's)."""
  placed = ("forward-facing: NDC rays" if context.found("forward") else
            "the masked subject's photo bounds" if context.effects.get("data.photo_bounds")
            else "")
  return depth_effects(context.photos, placed)


def flip_depth(result, base, context):
  """DS-NeRF's depth from the tracks off where auto turned it on."""
  if result.loss.depth.weight > 0:
    return {"loss.depth.weight": 0.0}, ""
  return None, ("auto left the depth from the tracks off (no tracks, more views than measured, "
                "or samples away from the points)")


RULE = Rule("depth", decide, row="depth from the tracks", fields=("loss.depth.weight",),
            flips={"depth": flip_depth})
