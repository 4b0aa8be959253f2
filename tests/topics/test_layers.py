"""The layering rules, checked on the syntax tree.

1. Imports run down the layers (LAYERS, lowest first): a module imports from its own folder and
   the folders below it, never above; UPWARD lists the arrows that still run up (none now).
2. No ConfigDict is read below the entry layer. Outside the entry modules (ENTRY: cli.py,
   run/, bench/, viewer/; the old-path aliases at the top of nerf_jax/ are checked,
   and read none) no function takes a `config` / `*_config` argument, no code reads a
   `config.` / `*_config.` attribute, and none reads an attribute named `config` (`exp.config`;
   jax.config, JAX's flags, aside): each layer
   receives its own small, typed settings, built once by run/components.py (docstrings and
   messages may name config fields). The data loaders, the train batches, the train step and
   the evaluator are below the entry layer.
"""

import ast
import pathlib
import re

import nerf_jax

PACKAGE = pathlib.Path(nerf_jax.__file__).parent
ENTRY = re.compile(r"^cli\.py$|^(run|bench|viewer)/")
CONFIG_NAME = re.compile(r"^(config|\w+_config)$")

# The folders of nerf_jax, lowest layer first; 'entry' is the rest (cli, viewer/, bench/,
# the old-path aliases) and configs/.
LAYERS = ("backend", "cameras", "volume", "fields", "samplers", "render", "data", "evaluate",
          "train", "run", "entry")
# Imports that still run up a layer, as (importing module, imported module): none (issue 39
# replaced them with settings, a step hook and backend/errors.py).
UPWARD = set()


def _below_entry():
  files = sorted(PACKAGE.rglob("*.py"))
  return [f for f in files if not ENTRY.search(f.relative_to(PACKAGE).as_posix())]


def config_uses(source):
  """[(line, what)] of config arguments, config attribute reads and reads of an attribute named
  `config` (other than jax.config) in `source`."""
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
    elif (isinstance(node, ast.Attribute) and node.attr == "config"
          and not (isinstance(node.value, ast.Name) and node.value.id == "jax")):
      found.append((node.lineno, f"reads {ast.unparse(node)}"))
  return found


def test_the_check_finds_what_it_looks_for():
  source = "def f(x, train_config):\n  return config.data.path\n"
  assert config_uses(source) == [(1, "argument train_config"), (2, "reads config.data")]
  assert not config_uses('def f(x):\n  """config.data.path"""\n  return "config.model"\n')
  assert config_uses("def f(exp):\n  return exp.config.data.ndc\n") == [(2, "reads exp.config")]
  assert config_uses("x = self.run.config\n") == [(1, "reads self.run.config")]
  assert not config_uses("import jax\nx = jax.config.jax_enable_x64\n")


def test_no_config_below_the_entry_layer():
  files = _below_entry()
  checked = {f.relative_to(PACKAGE).as_posix() for f in files}
  assert len(files) > 30 and {"render/renderer.py", "train/train_step.py", "data/loaders.py",
                              "data/process.py", "train/train_batches.py",
                              "evaluate/evaluation.py"} <= checked
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
