"""Atomic checkpoints of a training state: `workdir/checkpoints/ckpt_<step>.msgpack`.

A checkpoint is written to a temporary file, flushed to disk and renamed into place, so a run
killed at any moment leaves either the previous complete checkpoint or the new complete one.
A `model_signature` (the config fields that fix parameter shapes) is stored beside the state, so
restoring into an incompatible config is refused with a message instead of failing deep in Flax.
`meta` (a small JSON-able dict, e.g. the wall seconds spent) is stored in the same file, so it is
always consistent with the state it describes.
"""

import json
import os
import re

from flax import serialization

_NAME = re.compile(r"^ckpt_(\d+)\.msgpack$")


class CheckpointError(ValueError):
  """A checkpoint that cannot be used with the current config."""


def checkpoint_dir(workdir):
  return os.path.join(workdir, "checkpoints")


def list_steps(workdir):
  """Steps of the complete checkpoints in `workdir`, ascending."""
  folder = checkpoint_dir(workdir)
  if not os.path.isdir(folder):
    return []
  return sorted(int(m.group(1)) for m in map(_NAME.match, os.listdir(folder)) if m)


def latest_path(workdir):
  """Path of the newest checkpoint, or None."""
  steps = list_steps(workdir)
  return os.path.join(checkpoint_dir(workdir), f"ckpt_{steps[-1]}.msgpack") if steps else None


def atomic_write(path, data):
  """Write bytes `data` to `path` via a flushed temporary file and a rename."""
  tmp = f"{path}.tmp-{os.getpid()}"
  with open(tmp, "wb") as f:
    f.write(data)
    f.flush()
    os.fsync(f.fileno())
  os.replace(tmp, path)  # atomic on POSIX: readers see the old file or the new one
  try:  # make the rename itself durable (a power cut after this returns keeps the new file)
    fd = os.open(os.path.dirname(path) or ".", os.O_RDONLY)
    try:
      os.fsync(fd)
    finally:
      os.close(fd)
  except OSError:
    pass  # some filesystems cannot fsync a directory; the rename is still atomic


def save(workdir, step, state, signature, keep=2, meta=None):
  """Write `state` (a pytree) as the checkpoint of `step`; keep the newest `keep`. Returns path.

  meta: optional JSON-able dict stored with the state (read back by `restore_with_meta`).
  """
  folder = checkpoint_dir(workdir)
  os.makedirs(folder, exist_ok=True)
  for name in os.listdir(folder):  # temporaries left by a killed run are never complete
    if ".msgpack.tmp-" in name and not name.endswith(f".tmp-{os.getpid()}"):
      os.remove(os.path.join(folder, name))
  payload = {"state": serialization.to_state_dict(state), "signature": json.dumps(signature),
             "meta": json.dumps(meta or {})}
  path = os.path.join(folder, f"ckpt_{step}.msgpack")
  atomic_write(path, serialization.msgpack_serialize(payload))
  for old in list_steps(workdir)[:-keep]:
    os.remove(os.path.join(folder, f"ckpt_{old}.msgpack"))
  return path


def restore(path, template, signature):
  """Restore the state saved at `path` into the structure of `template`.

  Raises CheckpointError if the checkpoint's model signature differs from `signature`.
  """
  return restore_with_meta(path, template, signature)[0]


def restore_with_meta(path, template, signature, upgrade=None):
  """(state, meta) saved at `path`; see `restore`. meta is {} for checkpoints without one.

  upgrade: None, or fn(saved state dict) -> state dict in today's structure (older
  checkpoints)."""
  try:
    with open(path, "rb") as f:
      payload = serialization.msgpack_restore(f.read())
    saved = json.loads(payload["signature"])
  except Exception as e:  # msgpack raises several types for a damaged file
    raise CheckpointError(f"{path}: unreadable checkpoint ({type(e).__name__}); delete it to "
                          "resume from the one before, or use a new --workdir") from None
  if saved != json.loads(json.dumps(signature)):
    current = json.loads(json.dumps(signature))
    diffs = [f"{k}: checkpoint {saved.get(k)!r} vs config {current.get(k)!r}"
             for k in sorted(set(saved) | set(current)) if saved.get(k) != current.get(k)]
    raise CheckpointError(f"{path} was made with an incompatible config ({'; '.join(diffs)}); "
                          "use a new --workdir or the original config")
  try:
    saved_state = payload["state"] if upgrade is None else upgrade(payload["state"])
    state = serialization.from_state_dict(template, saved_state)
  except (ValueError, KeyError, TypeError) as e:
    first = str(e).splitlines()[0] if str(e) else type(e).__name__
    raise CheckpointError(f"{path} does not match the current config's training state "
                          f"({first[:160]}); was the optimizer config (e.g. train.grad_clip) "
                          "changed? Use a new --workdir or the original config") from None
  return state, json.loads(payload.get("meta", "{}"))
