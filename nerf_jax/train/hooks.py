"""The training loop's hooks (train/loop.py), each small and doing one thing when it is due:

  Watch       a watcher of the caller's (the live viewer): after every step
  Record      a log step's record (loss, PSNR, rays/s, the loss terms' stats): every log_every
              steps and at the final step
  Evaluate    the test views' PSNR into the record and their first view into TensorBoard:
              every eval_every steps, on log steps
  MetricsFile the record as one line of metrics.jsonl: on log steps
  TensorBoard the record's scalars: on log steps
  ProgressLine the progress bar, and a line per log step with the ETA
  Checkpoint  a checkpoint of the state: every checkpoint_every steps and at the final step

None reads a config: run/train_lib.py builds them from it.
"""

import json

import jax

from nerf_jax.evaluate import visuals
from nerf_jax.train import progress


class Hook:
  """A hook doing nothing: subclasses override `due` and `__call__` (and `close`)."""

  def due(self, end):
    del end
    return False

  def __call__(self, end):
    pass

  def close(self):
    pass


def every(step, steps):
  """Whether `step` is a multiple of `steps` (0: never)."""
  return bool(steps) and step % steps == 0


class Watch(Hook):
  """Runs a watcher (an object with after_step(step, variables_fn) and close(): the live
  viewer, viewer/training.py) after every step; variables(state) -> the state's variables on
  one device."""

  def __init__(self, watcher, variables):
    self.watcher, self.variables = watcher, variables

  def due(self, end):
    return True

  def __call__(self, end):
    self.watcher.after_step(end.step, lambda: self.variables(end.state))

  def close(self):
    self.watcher.close()


class Record(Hook):
  """Starts a log step's record: step, wall_seconds, loss, train_psnr (the colour term's psnr),
  rays_per_second and the other stats of the loss terms as '<term>/<stat>' (train/losses/: e.g.
  a sample budget's colour/rays_in_loss).

  log_every: steps between records. window: the progress.RateWindow of the training rate.
  rays_per_step: rays in a step. elapsed() -> the run's seconds so far. check(state): raises if
  the state has seen a non-finite step."""

  def __init__(self, log_every, window, rays_per_step, elapsed, check):
    self.log_every, self.window, self.rays_per_step = log_every, window, rays_per_step
    self.elapsed, self.check = elapsed, check
    self.rays_per_second = None  # the last record's: what the final evaluation's estimate uses

  def due(self, end):
    return every(end.step, self.log_every) or end.final

  def __call__(self, end):
    # The window ends when the device has done every step dispatched (progress.RateWindow).
    jax.block_until_ready((end.state, end.stats))
    end.rays_per_second = self.window.rate(end.step) * self.rays_per_step
    self.rays_per_second = end.rays_per_second
    stats = jax.device_get(end.stats)
    self.check(end.state)
    end.record = {"step": end.step, "wall_seconds": round(self.elapsed(), 3),
                  "loss": float(stats["loss"]), "train_psnr": float(stats["colour/psnr"]),
                  "rays_per_second": round(end.rays_per_second)}
    end.extra = {name: value.item() for name, value in stats.items()
                 if name not in ("loss", "colour/psnr")}
    end.record.update(end.extra)


def first_view_into(images, near, far):
  """An evaluator `on_view` callback putting the first view's TensorBoard images in `images`
  (near, far: the depth range of its colour map)."""
  def on_view(index, out, truth):
    if index == 0:
      images.update({"eval/rgb": visuals.to_uint8(out["rgb"]),
                     "eval/depth": visuals.colorize(out["depth"], near, far),
                     "eval/truth": visuals.to_uint8(truth)})
  return on_view


class Evaluate(Hook):
  """The test views' PSNR as the record's eval_psnr, every `eval_every` steps on log steps,
  outside the training rate's window; the first view's images go to TensorBoard.

  evaluate(variables, on_view) -> the evaluator's metrics; variables(state) -> the variables
  on one device; writer: summary.Writer; near, far: the depth images' range."""

  def __init__(self, eval_every, evaluate, variables, window, writer, near, far):
    self.eval_every, self.evaluate, self.variables = eval_every, evaluate, variables
    self.window, self.writer, self.near, self.far = window, writer, near, far

  def due(self, end):
    return end.record is not None and every(end.step, self.eval_every)

  def __call__(self, end):
    images = {}
    with self.window.excluded():
      end.record["eval_psnr"] = float(self.evaluate(
          self.variables(end.state), on_view=first_view_into(images, self.near, self.far))["psnr"])
      self.writer.images(end.step, images)


class MetricsFile(Hook):
  """Each log step's record as a line of JSON appended to `path` (metrics.jsonl)."""

  def __init__(self, path):
    self.path = path

  def due(self, end):
    return end.record is not None

  def __call__(self, end):
    append_json_line(self.path, end.record)


def append_json_line(path, record):
  with open(path, "a") as f:
    f.write(json.dumps(record) + "\n")


class TensorBoard(Hook):
  """Each log step's scalars: train/{loss, psnr, learning_rate, rays_per_second, the loss
  terms' stats} and eval/psnr when evaluated. writer: summary.Writer; schedule: count -> the
  learning rate."""

  def __init__(self, writer, schedule):
    self.writer, self.schedule = writer, schedule

  def due(self, end):
    return end.record is not None

  def __call__(self, end):
    record = end.record
    self.writer.scalars(end.step, {
        "train/loss": record["loss"], "train/psnr": record["train_psnr"],
        "train/learning_rate": float(self.schedule(end.step - 1)),
        "train/rays_per_second": end.rays_per_second,
        **{f"train/{name}": value for name, value in end.extra.items()},
        **({"eval/psnr": record["eval_psnr"]} if "eval_psnr" in record else {})})


class ProgressLine(Hook):
  """The progress bar (progress.Progress): redrawn when due, with a line per log step (loss,
  PSNR, rays/s, elapsed, ETA).

  planned: the steps the schedule plans; max_seconds: the time budget (0 = none); clocked: the
  clock, not a step count, ends the run (the bar counts seconds); start_step: the step the run
  (or its resumption) started at; elapsed() -> the run's seconds so far; stream: where the bar
  goes (None: stdout)."""

  def __init__(self, planned, max_seconds, clocked, start_step, elapsed, stream=None):
    self.planned, self.max_seconds, self.clocked = planned, max_seconds, clocked
    self.start_step, self.elapsed = start_step, elapsed
    self.bar = progress.Progress(int(max_seconds) if clocked else planned,
                                 "train (seconds)" if clocked else "train",
                                 start=self._position(start_step), stream=stream)

  def _position(self, step):
    return int(self.elapsed()) if self.clocked else step

  def due(self, end):
    return end.record is not None or self.bar.due()

  def __call__(self, end):
    if end.record is None:
      jax.block_until_ready(end.state.step)  # show steps done, not steps queued (a scalar sync)
      self.bar.update(self._position(end.step))
      return
    record = end.record
    wall = record["wall_seconds"]
    eta = max(self.planned - end.step, 0) * wall / max(end.step - self.start_step, 1)
    if self.max_seconds > 0:
      eta = max(min(eta, self.max_seconds - wall), 0.0)
    of = f" of {progress.format_seconds(self.max_seconds)}" if self.clocked else ""
    self.bar.update(self._position(end.step),
                    info=f"loss {record['loss']:.5f} psnr {record['train_psnr']:.2f}")
    self.bar.write(f"step {end.step}{'' if self.clocked else f'/{self.planned}'} "
                   f"loss {record['loss']:.5f} psnr {record['train_psnr']:.2f} "
                   f"{end.rays_per_second:,.0f} rays/s "
                   f"elapsed {progress.format_seconds(wall)}{of} "
                   f"eta {progress.format_seconds(eta)}")

  def close(self):
    self.bar.close()


class Checkpoint(Hook):
  """A checkpoint every `checkpoint_every` steps and at the final step (the last, the end of
  the time budget, a signal), outside the training rate's window, of a state that has seen no
  non-finite step. check(state): raises if it has; save(state): writes the checkpoint."""

  def __init__(self, checkpoint_every, window, check, save):
    self.checkpoint_every, self.window, self.check, self.save = (checkpoint_every, window,
                                                                 check, save)

  def due(self, end):
    return every(end.step, self.checkpoint_every) or end.final

  def __call__(self, end):
    with self.window.excluded():
      self.check(end.state)  # never checkpoint a state that has seen a bad step
      self.save(end.state)

