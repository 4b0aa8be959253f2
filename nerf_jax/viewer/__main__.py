"""Fly around a trained NeRF in the browser: `python -m nerf_jax.viewer`, `nerf-view`.

  pip install -e ".[viewer]"
  nerf-view --workdir=runs/fast            # then open the printed address
  nerf-view --workdir=runs/fast --port=7008 --host=0.0.0.0
"""

import time

from absl import app, flags

from nerf_jax.backend import errors
from nerf_jax.data import DataError
from nerf_jax.run import config_lib, experiment
from nerf_jax.run.settings import ViewerSettings
from nerf_jax.train import checkpoints

# Exceptions whose message is the whole story for the user: those of restoring a run (as
# nerf-render's, cli.USER_ERRORS) and the viewer's own (server.ViewerError, a ValueError).
USER_ERRORS = (DataError, checkpoints.CheckpointError, experiment.TrainingError,
               config_lib.ConfigError, FileNotFoundError, ValueError)


def serve(workdir, host, port, fps, still_height, out_dir):
  """Serve the newest checkpoint of `workdir` until interrupted."""
  from nerf_jax.viewer import scene, server  # pylint: disable=import-outside-toplevel
  server.import_viser()  # the missing-extra error before the model loads
  server.check_port(host, port)
  loaded, params, step = scene.from_workdir(workdir)
  print(f"restored step {step} from {workdir}", flush=True)
  viewer = server.Viewer(loaded, params, host=host, port=port, step=step, target_fps=fps,
                         still_height=still_height or None, out_dir=out_dir or workdir)
  print(f"viewer: open {viewer.url} (Ctrl-C stops)", flush=True)
  try:
    viewer.warmed.wait()
    print(f"viewer: every frame size compiled ({viewer.warm_s:.1f} s)", flush=True)
    while True:
      time.sleep(1.0)
  finally:
    viewer.close()


def main():
  """Define the flags, parse them (one-line errors) and serve."""
  workdir = flags.DEFINE_string("workdir", None, "Training run directory.", required=True)
  port = flags.DEFINE_integer("port", ViewerSettings.port, "Port to serve the page on.")
  host = flags.DEFINE_string("host", "127.0.0.1", "Address to listen on (0.0.0.0: all).")
  fps = flags.DEFINE_float("fps", 10.0, "Frames per second to hold while the camera moves.")
  still_height = flags.DEFINE_integer("still_height", 0, "Pixels per column of the still frame "
                                      "(0 = the training images').")
  out = flags.DEFINE_string("out", "", "Where 'Save path' writes (default: the workdir).")

  def run(argv):
    del argv
    errors.run_main(lambda: serve(workdir.value, host.value, port.value, fps.value,
                                  still_height.value, out.value), USER_ERRORS)

  app.run(run, flags_parser=errors.parse_flags)


if __name__ == "__main__":
  main()
