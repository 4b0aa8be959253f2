"""Progress with an ETA: a redrawn bar on a terminal, periodic plain lines in logs (CI, files).

  bar = Progress(total=600, desc="train")
  for step in ...:
    bar.update(step, info="loss 0.012")  # cheap: redraws at most every `interval` seconds
    bar.write("a line that stays")         # printed above the bar (or as is, off a terminal)
  bar.close()

`track(iterable, total, desc)` wraps a loop. The ETA is measured from the first update on, so a
slow first item (JIT compilation) does not inflate it.
"""

import contextlib
import sys
import time


def format_seconds(seconds):
  """'m:ss' (or 'h:mm:ss') of a non-negative duration."""
  seconds = int(max(seconds, 0))
  hours, rest = divmod(seconds, 3600)
  if hours:
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}"
  return f"{rest // 60}:{rest % 60:02d}"


class Progress:
  """A progress display of `count` out of `total` items.

  On a terminal (`stream.isatty()`) it redraws one line with `\\r` at most every `interval`
  seconds (default 0.2). Otherwise it prints a plain line when `interval` seconds (default 30)
  have passed since anything was last printed, so a CI log gets a heartbeat, not a flood.
  `start` is the count already done when the display starts (a resumed run).
  """

  def __init__(self, total, desc="", start=0, stream=None, interval=None, clock=time.monotonic):
    self.total, self.desc = max(int(total), 1), desc
    self.stream = stream or sys.stdout
    self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
    self.interval = interval if interval is not None else (0.2 if self.tty else 30.0)
    self._clock = clock
    self.count, self.info = int(start), ""
    self._t0 = clock()
    self._first = None  # (time, count) of the first update: the rate is measured from there
    self._last_print = self._t0
    self._printed = None  # the count shown by the last printed line
    self._drawn = False

  def elapsed(self):
    return self._clock() - self._t0

  def eta(self):
    """Seconds left at the rate since the first update; None before there is a rate."""
    if self._first is None:
      return None
    t1, c1 = self._first
    done = self.count - c1
    if done <= 0:
      return None
    return (self.total - self.count) * (self._clock() - t1) / done

  def due(self):
    """Whether an update now would print (callers may skip costly work, e.g. a device sync)."""
    return self._clock() - self._last_print >= self.interval

  def update(self, count=None, info=None, force=False):
    """Set the count (default: one more) and the trailing info text; print if due or forced."""
    self.count = self.count + 1 if count is None else int(count)
    if self._first is None:
      self._first = (self._clock(), self.count)
    if info is not None:
      self.info = info
    if force or self.due():
      self._print(self.line())

  def line(self):
    """The status text: 'desc 120/600 [####------] 20% info 0:12<0:48'."""
    frac = min(self.count / self.total, 1.0)
    eta = self.eta()
    times = f"{format_seconds(self.elapsed())}<{format_seconds(eta) if eta is not None else '?'}"
    bar = ""
    if self.tty:
      width = 20
      filled = int(frac * width)
      bar = " [" + "#" * filled + "-" * (width - filled) + "]"
    parts = [f"{self.desc} " if self.desc else "", f"{self.count}/{self.total}{bar} ",
             f"{100 * frac:3.0f}%", f" {self.info}" if self.info else "", f" {times}"]
    return "".join(parts)

  def write(self, text):
    """Print a line that stays (above the bar on a terminal)."""
    if self.tty and self._drawn:
      self.stream.write("\r\033[K")
    self.stream.write(text + "\n")
    if self.tty and self._drawn:
      self.stream.write(self.line())
    self.stream.flush()
    if not self.tty:
      self._last_print, self._printed = self._clock(), self.count

  def _print(self, text):
    if self.tty:
      self.stream.write("\r\033[K" + text)
      self._drawn = True
    else:
      self.stream.write(text + "\n")
    self.stream.flush()
    self._last_print, self._printed = self._clock(), self.count

  def close(self):
    """Show the final state (a terminal keeps the bar; a log gets a last line if it is new)."""
    if self.tty:
      self._print(self.line())
      self.stream.write("\n")
      self.stream.flush()
      self._drawn = False
    elif self._printed != self.count:
      self._print(self.line())

  def __enter__(self):
    return self

  def __exit__(self, *exc):
    self.close()


class RateWindow:
  """Items per second of the work between two reads, less the time spent in `excluded()`.

  On an asynchronous device (a GPU) the host runs ahead of the device, so a clock read between
  two host-side prints times whatever happened to block. The caller blocks on the device's
  result (`jax.block_until_ready`) before each `rate` call, so every window starts and ends with
  the device idle; evaluations and checkpoints inside `excluded()` are left out of the window.
  """

  def __init__(self, count=0, clock=time.perf_counter):
    self._clock = clock
    self._count, self._start, self._excluded = int(count), clock(), 0.0

  @contextlib.contextmanager
  def excluded(self):
    """A block of work that does not count in the window (an evaluation, a checkpoint)."""
    start = self._clock()
    try:
      yield
    finally:
      self._excluded += self._clock() - start

  def rate(self, count):
    """Items per second from the window's start to now, count being the items done so far;
    starts the next window."""
    now = self._clock()
    seconds = max(now - self._start - self._excluded, 1e-9)
    rate = (int(count) - self._count) / seconds
    self._count, self._start, self._excluded = int(count), now, 0.0
    return rate


def track(iterable, total=None, desc="", **kwargs):
  """Iterate `iterable` while showing a `Progress` (total: len(iterable) when None)."""
  total = len(iterable) if total is None else total
  with Progress(total, desc, **kwargs) as bar:
    for item in iterable:
      yield item
      bar.update()
