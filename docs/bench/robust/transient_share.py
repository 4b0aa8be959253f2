"""Warm up a built-in scene briefly (no transient handling, no codes; 48 px, 50 views, 1024
rays a step), render its training views and print run/auto/transient_share.transient_share (appended to
transient_share.jsonl). docs/photo_collections.md has the numbers.

  PYTHONPATH=$PWD python docs/bench/robust/transient_share.py crowd fast 300
"""
import json
import sys

import numpy as np

from nerf_jax.render import background, image_renderer
from nerf_jax.run import config_lib, experiment, train_lib
from nerf_jax.run.auto import transient_share

scene, base, steps = sys.argv[1], sys.argv[2], int(sys.argv[3])
config = config_lib.load(base)
config.data.scene = scene
config.data.image_size = 48
config.data.num_views = 50
config.model.appearance_dims = 0
config.train.max_steps = steps
config.train.max_seconds = 0.0
config.train.batch_rays = 1024
config.train.tensorboard = False
config.train.log_every = 100
config.render.video_frames = 0
config.train.checkpoint_every = steps
workdir = f"/tmp/transient_share_{scene}"
train_lib.train_and_evaluate(config, workdir)
exp, state = experiment.restore(workdir)
draw = image_renderer.make_image_renderer(exp.renderer, exp.image)(state.variables)
bg = np.asarray(background.parse(exp.config.data.background), np.float32)
photos = background.images_on_background(exp.train_ds, bg)[1]
renders = np.stack([np.asarray(draw(exp.rays(p), bg)["rgb"]) for p in exp.train_ds.poses])
share, shares = transient_share.transient_share(photos, renders)
out = {"scene": scene, "base": base, "steps": steps, "share": share,
       "photos_over_1pc": float(np.mean(shares > 0.01)), "max": float(shares.max())}
print(json.dumps(out))
with open("transient_share.jsonl", "a") as f:
  f.write(json.dumps(out) + "\n")
