"""The benchmarks' records: one shape, one way to write and read them.

Every record a benchmark writes is its own fields, `stamp`ed with the fields every record
carries (STAMP):
  date     when it was written, UTC ('2026-11-29 14:05 UTC', DATE_FORMAT: sorts as text)
  git      the commit of the code that wrote it (run/machine.py's git_revision; '-dirty' where
           tracked files differ from it; None outside a git checkout)
  machine  run/machine.py's record: what the machine is (CPU model and count, memory, backend,
           devices, jax) and, where measured, its load over the run and the busy verdict
Records go one a line into JSON-lines files (`append`, or `write` for a file rewritten whole)
and come back with `read`. Older records, written before the stamp, read as they are.

Nothing here starts JAX's backend unless `stamp` has to describe the machine itself.
"""

import datetime
import json
import os

from nerf_jax.data.dataset import DataError
from nerf_jax.run import machine as machine_lib

STAMP = ("date", "git", "machine")  # the fields every record carries
DATE_FORMAT = "%Y-%m-%d %H:%M UTC"


def now():
  """The time now, UTC, as a record's date (DATE_FORMAT)."""
  return datetime.datetime.now(datetime.timezone.utc).strftime(DATE_FORMAT)


def stamp(record, measured=None):
  """A copy of the dict `record` with STAMP's fields: 'date' (`now`), 'git' (the code's
  revision) and 'machine': `measured` (a machine.Sampler's record, the machine and its load
  over the run, or a run's metrics.json 'machine'), else the record's own 'machine' where it
  is a dict, else machine.describe() (what the machine is, no load: this starts JAX's backend,
  so a parent that runs its work in children on a GPU passes a child's record)."""
  machine = measured if measured is not None else record.get("machine")
  if not isinstance(machine, dict):
    machine = machine_lib.describe()
  return {**record, "date": now(), "git": machine_lib.git_revision(), "machine": machine}


def append(path, record):
  """Append `record` (a dict) to the JSON-lines file `path` as one line, making its folder."""
  text = json.dumps(record) + "\n"  # whole before the file opens: a bad field writes nothing
  os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
  with open(path, "a") as f:
    f.write(text)


def write(path, records):
  """Write the JSON-lines file `path` anew: `records` (dicts), one a line."""
  text = "".join(json.dumps(r) + "\n" for r in records)
  os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
  with open(path, "w") as f:
    f.write(text)


def read(path):
  """The records (dicts) of the JSON-lines file `path`, oldest first; [] where it does not
  exist. Blank lines are skipped; a line that is no JSON object is a DataError naming the
  file and line."""
  if not os.path.exists(path):
    return []
  out = []
  with open(path) as f:
    for number, text in enumerate(f, 1):
      if not text.strip():
        continue
      try:
        record = json.loads(text)
      except json.JSONDecodeError as e:
        raise DataError(f"{path}:{number}: not a JSON record ({e.msg})") from None
      if not isinstance(record, dict):
        raise DataError(f"{path}:{number}: not a JSON object")
      out.append(record)
  return out
