"""The live viewer: fly around a trained model, or one in training, in the browser (viser).

__main__.py  `python -m nerf_jax.viewer` (nerf-view): serve a trained workdir's newest checkpoint
camera.py  viser's cameras <-> ours (OpenCV vs OpenGL axes, scale); frame intrinsics
policy.py  the resolution policy, the render-rate meter and cancellable chunked rendering
paths.py   camera paths: key cameras, interpolation, the files render.py reads
scene.py   the one adapter onto the renderer: what to draw and how (checkpoint or live params)
server.py  the viser page and its render loop (needs the `viewer` extra)
"""
