"""The layering rules, checked on the syntax tree.

1. Imports run down the layers (LAYERS, lowest first): a module imports from its own folder and
   the folders below it, never above; UPWARD lists the arrows that still run up, to be removed.
2. No ConfigDict is read below the entry layer. Outside the entry modules (cli, view,
   run/{experiment,config_lib,auto,outputs,train_lib}, train/train_batches.py,
   evaluate/evaluation.py, bench/, viewer/, data/loaders.py) no function takes a `config` /
   `*_config` argument and no code reads a `config.` / `*_config.` attribute: each layer
   receives its own small, typed settings, built once by experiment.py (docstrings and messages
   may name config fields). The train step is below the entry layer.
"""

import ast
import pathlib
import re

import nerf_jax

PACKAGE = pathlib.Path(nerf_jax.__file__).parent
ENTRY = re.compile(r"^(cli|view)\.py$|^run/(experiment|config_lib|auto|outputs|train_lib)\.py$|"
                   r"^train/train_batches\.py$|^evaluate/evaluation\.py$|^(bench|viewer)/|"
                   r"^data/loaders\.py$")
CONFIG_NAME = re.compile(r"^(config|\w+_config)$")

# The folders of nerf_jax, lowest layer first; 'entry' is the rest (cli, view, viewer/, bench/,
# the old-path aliases) and configs/.
LAYERS = ("backend", "cameras", "fields", "samplers", "render", "data", "evaluate", "train",
          "run", "entry")
# Imports that still run up a layer (issue 39: hooks and settings instead), as
# (importing module, imported module).
UPWARD = {
    ("data/loaders.py", "nerf_jax.run"),  # the loader completes a config (config_lib)
    ("data/process.py", "nerf_jax.cli"),  # nerf-process shares the CLI's one-line errors
    ("run/train_lib.py", "nerf_jax.viewer"),  # the live viewer, not yet a step hook
}


def _below_entry():
  files = sorted(PACKAGE.rglob("*.py"))
  return [f for f in files if not ENTRY.search(f.relative_to(PACKAGE).as_posix())]


def config_uses(source):
  """[(line, what)] of config arguments and config attribute reads in `source`."""
  found = []
  for node in ast.walk(ast.parse(source)):
    if isinstance(node, (ast.FunctionDef, ast.Lambda)):
      args = node.args
      for arg in args.posonlyargs + args.args + args.kwonlyargs:
        if CONFIG_NAME.match(arg.arg):
          found.append((node.lineno, f"argument {arg.arg}"))
    elif (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
          and CONFIG_NAME.match(node.value.id)):
      found.append((node.lineno, f"reads {node.value.id}.{node.attr}"))
  return found


def test_the_check_finds_what_it_looks_for():
  source = "def f(x, train_config):\n  return config.data.path\n"
  assert config_uses(source) == [(1, "argument train_config"), (2, "reads config.data")]
  assert not config_uses('def f(x):\n  """config.data.path"""\n  return "config.model"\n')


def test_no_config_below_the_entry_layer():
  files = _below_entry()
  checked = {f.relative_to(PACKAGE).as_posix() for f in files}
  assert len(files) > 30 and {"render/renderer.py", "train/train_step.py"} <= checked
  uses = [f"{f.relative_to(PACKAGE)}:{line}: {what}" for f in files
          for line, what in config_uses(f.read_text())]
  assert not uses, "\n".join(uses)


def _layer(name):
  """The layer of a module path relative to nerf_jax/ ('cameras/rays.py') or of a dotted module
  name below nerf_jax ('cameras.rays')."""
  first = re.split(r"[/.]", name)[0]
  return first if first in LAYERS else "entry"


def _imports(path):
  """The nerf_jax modules `path` imports (for `from nerf_jax import x`: nerf_jax.x)."""
  found = set()
  for node in ast.walk(ast.parse(path.read_text())):
    if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("nerf_jax"):
      if node.module == "nerf_jax":
        found |= {f"nerf_jax.{a.name}" for a in node.names}
      else:
        found.add(node.module)
    elif isinstance(node, ast.Import):
      found |= {a.name for a in node.names if a.name.startswith("nerf_jax.")}
  return found


def test_imports_run_down_the_layers():
  upward = set()
  for path in sorted(PACKAGE.rglob("*.py")):
    rel = path.relative_to(PACKAGE).as_posix()
    for module in _imports(path):
      target = _layer(module[len("nerf_jax."):])
      if module == "nerf_jax.configs" or module.startswith("nerf_jax.configs."):
        continue  # the configs are data, read by name
      if LAYERS.index(target) > LAYERS.index(_layer(rel)):
        upward.add((rel, module))
  assert upward <= UPWARD, sorted(upward - UPWARD)
  assert UPWARD <= upward, f"gone, remove from UPWARD: {sorted(UPWARD - upward)}"
