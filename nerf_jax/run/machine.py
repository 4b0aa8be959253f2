"""The machine a run's figures belong to, measured: what it is (CPU model and count, memory, jax,
its backend and devices, Python, the code's git revision; no host name) and how loaded it was
while the run went (`Sampler`), with a verdict: a run on a busy machine says so (`busy`), for
its time axis (steps, seconds, rates) is then not the code's alone.

Load, sampled every SAMPLE_SECONDS by a background thread from start to `Sampler.stop`:
  load        the 1-minute load average (os.getloadavg): start, end, mean and max of the samples.
  others_cpu  the CPU time that processes other than this one took on the CPUs this process may
              run on (its affinity set), per such CPU: 0 = they took none, 1 = a whole core
              each. From /proc/stat's per-CPU busy time (user, nice, system, irq, softirq and
              steal: a VM's neighbours take steal) less this process's own (/proc/self/stat,
              its ended children included); mean over the run and max over the intervals of
              at least MIN_INTERVAL seconds. None where /proc is not there (not Linux) or
              the run lasted under MIN_INTERVAL (a few clock ticks).
Busy (`verdict`): others_cpu's mean above OTHERS_BUSY; where it is not measured, the mean load
above the run's CPUs by more than LOAD_MARGIN.
"""

import os
import platform
import subprocess
import threading
import time
import weakref

SAMPLE_SECONDS = 5.0  # the background sampler's period
MIN_INTERVAL = 1.0  # shorter intervals (a few clock ticks) count in the mean, not the max
OTHERS_BUSY = 0.25  # busy: others took more than this share of each of the run's CPUs (mean)
LOAD_MARGIN = 1.0  # busy where others_cpu is unmeasured: mean load > the run's CPUs + this
RULE = (f"others_cpu mean > {OTHERS_BUSY:g} of each CPU the run may use; unmeasured: mean load "
        f"average > its CPUs + {LOAD_MARGIN:g}")
# The checkout holding the nerf_jax package (its git revision is the code's).
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def cpu_model():
  """The CPU's model name: /proc/cpuinfo's 'model name', else platform.processor() or
  platform.machine(), else 'unknown'."""
  try:
    with open("/proc/cpuinfo") as f:
      for line in f:
        if line.startswith("model name"):
          return line.split(":", 1)[1].strip()
  except OSError:
    pass
  return platform.processor() or platform.machine() or "unknown"


def run_cpus():
  """The sorted ids of the CPUs this process may run on (its affinity set), or None where the
  platform does not say (not Linux)."""
  if not hasattr(os, "sched_getaffinity"):
    return None
  return sorted(os.sched_getaffinity(0))


def memory_gb():
  """The machine's physical memory in GiB, or None where the platform does not say."""
  try:
    return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
  except (AttributeError, OSError, ValueError):
    return None


def _git(*args):
  return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=10,
                        check=True).stdout.strip()


def git_revision():
  """The commit of the code ('-dirty' added where tracked files differ from it), or None where
  the package is not in a git checkout of its own (installed, git missing). Never raises."""
  try:
    if os.path.realpath(_git("rev-parse", "--show-toplevel")) != os.path.realpath(ROOT):
      return None
    dirty = _git("status", "--porcelain", "--untracked-files=no")
    return _git("rev-parse", "HEAD") + ("-dirty" if dirty else "")
  except (OSError, subprocess.SubprocessError):
    return None


def describe():
  """What the machine and software are: {'cpu_model', 'cpu_count' (logical CPUs),
  'cpus_used' (those this process may run on), 'memory_gb', 'platform', 'python', 'jax',
  'jaxlib', 'backend', 'device_kind', 'device_count', 'devices' (each device's kind), 'git'}."""
  import jax  # pylint: disable=import-outside-toplevel  (describe alone starts jax's backend)
  import jaxlib  # pylint: disable=import-outside-toplevel
  cpus, devices = run_cpus(), jax.devices()
  return {"cpu_model": cpu_model(), "cpu_count": os.cpu_count(),
          "cpus_used": len(cpus) if cpus else os.cpu_count(), "memory_gb": memory_gb(),
          "platform": platform.platform(), "python": platform.python_version(),
          "jax": jax.__version__, "jaxlib": jaxlib.__version__,
          "backend": jax.default_backend(), "device_kind": devices[0].device_kind,
          "device_count": len(devices), "devices": [d.device_kind for d in devices],
          "git": git_revision()}


# ------------------------------------------------------------------------------ the load


def _busy_ticks(cpus):
  """The clock ticks the CPUs `cpus` (ids) have been busy since boot (/proc/stat: user, nice,
  system, irq, softirq, steal; guest time is inside user), or None without /proc/stat."""
  if cpus is None:
    return None
  wanted = {f"cpu{c}" for c in cpus}
  try:
    with open("/proc/stat") as f:
      rows = [line.split() for line in f if line.startswith("cpu")]
  except OSError:
    return None
  total = 0
  for row in rows:
    if row[0] in wanted:
      ticks = [int(x) for x in row[1:9]]  # user nice system idle iowait irq softirq steal
      total += sum(ticks[:3]) + sum(ticks[5:8])
  return total


def _own_ticks():
  """The clock ticks this process (every thread) and its ended children have run, or None
  without /proc/self/stat."""
  try:
    with open("/proc/self/stat") as f:
      text = f.read()
  except OSError:
    return None
  # After the name's closing parenthesis (a name may hold spaces): fields[0] is field 3, state.
  fields = text[text.rindex(")") + 2:].split()
  return sum(int(x) for x in fields[11:15])  # utime, stime, cutime, cstime (fields 14-17)


def _load():
  try:
    return os.getloadavg()[0]
  except (AttributeError, OSError):
    return None


def snapshot(cpus):
  """One sample: {'time': monotonic seconds, 'load': the 1-minute load average or None,
  'busy': busy ticks of `cpus` or None, 'own': this process's ticks or None}."""
  return {"time": time.monotonic(), "load": _load(), "busy": _busy_ticks(cpus),
          "own": _own_ticks()}


def load_summary(samples, cpus_used, ticks_per_second):
  """The load over `samples` (snapshots in time order, at least one): {'seconds', 'samples',
  'load': {'start', 'end', 'mean', 'max'} or None, 'others_cpu': {'mean', 'max'} or None}
  (see the module's docstring; others_cpu per CPU of the `cpus_used`). ticks_per_second: the
  clock ticks of /proc (os.sysconf('SC_CLK_TCK'))."""
  seconds = samples[-1]["time"] - samples[0]["time"]
  loads = [s["load"] for s in samples if s["load"] is not None]
  load = None if not loads else {"start": round(loads[0], 2), "end": round(loads[-1], 2),
                                 "mean": round(sum(loads) / len(loads), 2),
                                 "max": round(max(loads), 2)}

  def others(a, b):  # cores per run CPU; own time counted a tick late may exceed the busy time
    ticks = max(0, (b["busy"] - a["busy"]) - (b["own"] - a["own"]))
    return ticks / ticks_per_second / (b["time"] - a["time"]) / cpus_used

  measured = all(s["busy"] is not None and s["own"] is not None for s in samples)
  others_cpu = None
  if measured and seconds >= MIN_INTERVAL:  # a few clock ticks are no measurement
    pairs = [(a, b) for a, b in zip(samples, samples[1:])
             if b["time"] - a["time"] >= MIN_INTERVAL]
    mean = others(samples[0], samples[-1])
    peak = max((others(a, b) for a, b in pairs), default=mean)
    others_cpu = {"mean": round(mean, 3), "max": round(max(peak, mean), 3)}
  return {"seconds": round(seconds, 2), "samples": len(samples), "load": load,
          "others_cpu": others_cpu}


def verdict(others_mean, load_mean, cpus_used):
  """(busy: bool, why: a short phrase or None) of a run's others_cpu mean (None: unmeasured) and
  mean load average (None: unknown) on `cpus_used` CPUs; the rule is RULE."""
  load = "" if load_mean is None else f"load {load_mean:.1f} on {cpus_used} CPUs"
  if others_mean is not None:
    if others_mean > OTHERS_BUSY:
      return True, f"others took {others_mean:.2f} of each of {cpus_used} CPUs" + (
          f", {load}" if load else "")
    return False, None
  if load_mean is not None and load_mean > cpus_used + LOAD_MARGIN:
    return True, load
  return False, None


def _sample_until(done, samples, cpus, every):
  """The sampler thread: a snapshot every `every` seconds until `done` is set."""
  while not done.wait(every):
    samples.append(snapshot(cpus))


class Sampler:
  """Samples the machine's load from construction until `stop` in a daemon thread (a few small
  /proc reads every SAMPLE_SECONDS). A sampler dropped without `stop` (a run that raised) ends
  its thread when it is garbage-collected."""

  def __init__(self, every=SAMPLE_SECONDS):
    self._cpus = run_cpus()
    self._samples = [snapshot(self._cpus)]
    self._done = threading.Event()
    # The thread holds the samples and the event, not the sampler: finalize can run.
    self._thread = threading.Thread(target=_sample_until, name="machine-load", daemon=True,
                                    args=(self._done, self._samples, self._cpus, every))
    self._thread.start()
    weakref.finalize(self, self._done.set)
    self._record = None

  def stop(self):
    """The machine record: `describe()`'s fields, `load_summary`'s over the run, 'busy' (bool),
    'busy_why' (the figure that made it busy, or None) and 'busy_rule' (RULE). The first call
    stops sampling; later calls return the same record."""
    if self._record is None:
      self._done.set()
      self._thread.join()
      self._samples.append(snapshot(self._cpus))
      record = describe()
      cpus = record["cpus_used"]
      ticks = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
      record.update(load_summary(self._samples, cpus, ticks))
      others_cpu, load = record["others_cpu"], record["load"]
      busy, why = verdict(others_cpu and others_cpu["mean"], load and load["mean"], cpus)
      record.update(busy=busy, busy_why=why, busy_rule=RULE)
      self._record = record
    return self._record


def rates(steps, rays_per_step, seconds):
  """{'steps_per_second', 'rays_per_second'} of `steps` steps of `rays_per_step` rays each in
  `seconds` (> 0; ValueError otherwise)."""
  if not seconds > 0:
    raise ValueError(f"seconds={seconds}: a rate needs a positive time")
  return {"steps_per_second": steps / seconds, "rays_per_second": steps * rays_per_step / seconds}


def busy_note(machine):
  """' (busy: WHY)' for a machine record that says the machine was busy, else '' (no record,
  an older record without the verdict, or an idle machine)."""
  if not isinstance(machine, dict) or not machine.get("busy"):
    return ""
  return f" (busy: {machine.get('busy_why') or 'see its machine record'})"
