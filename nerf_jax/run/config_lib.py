"""Finding and loading configs: the files in configs/ (installed as `nerf_jax.configs`) and the
`config.json` a run saves in its workdir.

A config is named by a path (`configs/fast.py`, `my/exp.py`) or, from any directory, by its name
under configs/ (`fast`, `scenes/fog`); `:arg` after either is passed to `get_config(arg)` as
ml_collections' config_flags does. A saved config is completed with the schema's defaults
(run/schema.py, configs/default.py's values) for fields it lacks (written before they existed),
so the defaults live in one place.
"""

import dataclasses
import importlib.resources
import importlib.util
import json
import os

import ml_collections

from nerf_jax.run import schema


class ConfigError(ValueError):
  """A config name, file or saved config that cannot be used; the message says which."""


def configs_dir():
  """The directory of the installed configs (the repository's configs/)."""
  return str(importlib.resources.files("nerf_jax.configs"))


def resolve(spec):
  """The file path for `spec` = PATH or NAME, with any ':arg' suffix kept.

  An existing path wins; else NAME (with or without '.py', with or without a leading
  'configs/') under the installed configs/. ConfigError if neither exists.
  """
  path, colon, arg = spec.partition(":")
  if os.path.isfile(path):
    return spec
  name = path[len("configs/"):] if path.startswith("configs/") else path
  name = name if name.endswith(".py") else name + ".py"
  installed = os.path.join(configs_dir(), name)
  if os.path.isfile(installed):
    return installed + colon + arg
  known = ", ".join(available())
  raise ConfigError(f"--config={spec}: no such config file or name (names: {known})")


def available():
  """Names of the installed configs: ['debug', 'default', ..., 'scenes/fog', ...]."""
  root, names = configs_dir(), []
  for folder, _, files in os.walk(root):
    rel = os.path.relpath(folder, root)
    names += [os.path.normpath(os.path.join(rel, f[:-3])) for f in files
              if f.endswith(".py") and f != "__init__.py"]
  return sorted(names)


def load(spec):
  """The ConfigDict of `spec` (see `resolve`); ConfigError with one line if the file fails."""
  path = resolve(spec)
  path, _, arg = path.partition(":")
  try:
    module_spec = importlib.util.spec_from_file_location("_nerf_jax_config", path)
    module = importlib.util.module_from_spec(module_spec)
    module_spec.loader.exec_module(module)
    return module.get_config(arg) if arg else module.get_config()
  except Exception as e:  # pylint: disable=broad-except  (any error in the user's file)
    raise ConfigError(f"--config={spec}: cannot load the config file "
                      f"({type(e).__name__}: {_last_line(e)})") from e


def _last_line(exc):
  lines = [l.strip() for l in str(exc).splitlines() if l.strip()]
  return lines[-1] if lines else type(exc).__name__


def default():
  """The default config (configs/default.py's): every field, at its default (schema.defaults)."""
  return schema.defaults()


# Every section of the config (dotted path, '' = the top level) -> the settings dataclasses
# that declare its keys: the shared ones (schema.SECTIONS) and the built-in components' own.
SECTIONS = schema.all_sections()


# Fields that moved: old dotted name -> new one. A config, override or config.json using the
# old name keeps working (`upgrade` moves it, with one deprecation line).
RENAMED = {
    "model.grid_resolutions": "model.grid.resolutions",
    "model.grid_features": "model.grid.features",
    "model.hash_levels": "model.hash.levels",
    "model.hash_log2_size": "model.hash.log2_size",
    "model.hash_features": "model.hash.features",
    "model.hash_base_resolution": "model.hash.base_resolution",
    "model.hash_max_resolution": "model.hash.max_resolution",
    "model.hash_dtype": "model.hash.gather_dtype",
    "train.coarse_loss_weight": "loss.colour.coarse_weight",
    "train.huber_delta": "loss.colour.huber_delta",
    "train.distortion_weight": "loss.distortion.weight",
    "train.pose_prior": "loss.pose_prior.weight",
    "train.tv_weight": "loss.total_variation.weight",
    "render.appearance_protocol": "eval.appearance",
}


def renamed(field):
  """The current dotted name of `field` (itself unless it is in RENAMED)."""
  return RENAMED.get(field, field)


def deprecation(old, new):
  """The one line printed when an old spelling is used."""
  return f"note: config.{old} is deprecated; use config.{new}"


def _upgraded_dict(values, quiet=False):
  """`values` (a nested dict) with every RENAMED field moved to its new name, and the old
  data.background='random' turned into 'black' + train.random_background=True."""
  values = json.loads(json.dumps(values))  # a copy: the caller's dict is left as it is
  for old, new in RENAMED.items():
    *old_path, old_name = old.split(".")
    parent = values
    for part in old_path:
      parent = parent.get(part) if isinstance(parent, dict) else None
    if not isinstance(parent, dict) or old_name not in parent:
      continue
    value = parent.pop(old_name)
    *new_path, new_name = new.split(".")
    node = values
    for part in new_path:
      node = node.setdefault(part, {})
    node[new_name] = value
    if not quiet:
      print(deprecation(old, new), flush=True)
  data = values.get("data", {})
  if data.get("background") == "random":
    data["background"] = "black"  # the colour 'random' rendered and was scored on
    values.setdefault("train", {})["random_background"] = True
    if not quiet:
      print(deprecation("data.background='random'", "train.random_background=True (on the "
                        "data.background it is scored on)"), flush=True)
  return values


def upgrade(config):
  """`config` (a ConfigDict) with old spellings moved to the current fields (RENAMED, the
  random background), one deprecation line each; `config` itself if it has none."""
  values = config.to_dict()
  upgraded = _upgraded_dict(values)
  if upgraded == json.loads(json.dumps(values)):
    return config
  return complete(upgraded)


def complete(saved):
  """A ConfigDict of `saved` (a dict, e.g. a run's config.json) with the default's value for
  every field it lacks; tuples come back as tuples (JSON stores lists). Fields the default does
  not have are kept as they are; old spellings are moved (`upgrade`) without a word."""
  return ml_collections.ConfigDict(_merge(default().to_dict(), _as_trained(
      _upgraded_dict(saved, quiet=True))))


def _as_trained(saved):
  """`saved` with the fields a run saved before they existed set to what it trained with, not
  today's defaults: its appearance codes learnt at train.lr, its pose corrections without a
  prior."""
  train = saved.get("train")
  if not isinstance(train, dict):
    return saved
  if "appearance_lr" not in train and "lr" in train:
    train["appearance_lr"] = train["lr"]
  # Corrections learnt without the prior (train.pose_prior, now loss.pose_prior.weight, moved
  # by `_upgraded_dict` where the run had it).
  prior = saved.setdefault("loss", {}).setdefault("pose_prior", {})
  if isinstance(prior, dict) and "weight" not in prior:
    prior["weight"] = 0.0
  return saved


def _merge(base, saved):
  out = dict(base)
  for key, value in saved.items():
    if isinstance(base.get(key), dict) and isinstance(value, dict):
      out[key] = _merge(base[key], value)
    elif isinstance(base.get(key), tuple) and isinstance(value, list):
      out[key] = tuple(value)
    else:
      out[key] = value
  return out


def load_saved(workdir):
  """The completed config a run saved in `workdir/config.json`."""
  path = os.path.join(workdir, "config.json")
  if not os.path.exists(path):
    raise ConfigError(f"{path} not found: is {workdir} a training workdir?")
  try:
    with open(path) as f:
      saved = json.load(f)
  except (OSError, ValueError) as e:
    raise ConfigError(f"{path}: cannot read the saved config ({e})") from None
  return _without_retired(complete(saved), path)


def _without_retired(config, path):
  """`config` less the settings a saved run has that no settings dataclass declares any more
  (a field retired since it trained: it changes nothing now), one line each; so an old run
  still restores, while a config file's misspelt field stays an error (builders.check_config).
  """
  for section_path, classes in SECTIONS.items():
    section = section_at(config, section_path)
    if section is None:
      continue
    declared = {f.name for cls in classes for f in dataclasses.fields(cls)}
    for name in [k for k, v in section.items()
                 if k not in declared and not isinstance(v, ml_collections.ConfigDict)]:
      del section[name]
      where = f"{section_path}.{name}" if section_path else name
      print(f"note: {path}: config.{where} is no longer a setting; ignored", flush=True)
  return config


def get_field(config, field):
  """The value of the dotted `field` of `config` (a ConfigDict)."""
  node = config
  for part in field.split("."):
    node = node[part]
  return node


def section_at(config, path):
  """The section of `config` (a ConfigDict) at dotted `path` ('' = the config itself), or None
  where it has none."""
  node = config
  for part in filter(None, path.split(".")):
    node = node.get(part) if isinstance(node, ml_collections.ConfigDict) else None
  return node if isinstance(node, ml_collections.ConfigDict) else None


def set_field(config, field, value):
  """Set the dotted `field` of `config` (a ConfigDict) to `value`."""
  *path, last = field.split(".")
  node = config
  for part in path:
    node = node[part]
  node[last] = value


def unknown_override(config, field):
  """None if `config` has the dotted `field`, else one line naming the missing part."""
  node, known = config, ["config"]
  for part in field.split("."):
    if not isinstance(node, ml_collections.ConfigDict) or part not in node:
      valid = (f" (fields: {', '.join(sorted(node.keys()))})"
               if isinstance(node, ml_collections.ConfigDict) else "")
      return f"--config.{field}: {'.'.join(known)} has no field {part!r}{valid}"
    node, known = node[part], known + [part]
  return None
