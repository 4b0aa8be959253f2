"""The layering rules, checked on the syntax tree.

1. Imports run down the layers (LAYERS, lowest first): a module imports from its own folder and
   the folders below it, never above; UPWARD lists the arrows that still run up (none now).
   The config files (configs/, `nerf_jax.configs`) are in the entry layer: the library reads
   the config's schema from run/schema.py, never from a config file.
   No module reaches itself through imports either (imports inside functions included): no
   import circles, within a folder or across folders.
2. No ConfigDict is read below the entry layer. Outside the entry modules (ENTRY: cli.py,
   run/, bench/, viewer/; the old-path aliases at the top of nerf_jax/ are checked,
   and read none) no function takes a `config` / `*_config` argument, no code reads a
   `config.` / `*_config.` attribute, and none reads an attribute named `config` (`exp.config`;
   jax.config, JAX's flags, aside): each layer
   receives its own small, typed settings, built once by run/builders.py (docstrings and
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
# the old-path aliases) and configs/ (installed as nerf_jax.configs): a config file may import
# the library, no library module (run/ and below) imports a config file.
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
      target = _layer(module[len("nerf_jax."):])  # nerf_jax.configs: the entry layer's
      if LAYERS.index(target) > LAYERS.index(_layer(rel)):
        upward.add((rel, module))
  assert upward <= UPWARD, sorted(upward - UPWARD)
  assert UPWARD <= upward, f"gone, remove from UPWARD: {sorted(UPWARD - upward)}"


def test_a_config_file_is_above_the_library_and_the_viewer_below_the_command_line():
  # A library module importing a config file is an arrow up the layers, caught above.
  assert LAYERS.index(_layer("configs.default")) > LAYERS.index(_layer("run/config_lib.py"))
  # The viewer is a part the command line hands down (cli.TRAIN_WATCHERS): it imports no cli.
  viewer = sorted((PACKAGE / "viewer").rglob("*.py"))
  assert len(viewer) > 3 and not [p.name for p in viewer if "nerf_jax.cli" in _imports(p)]


def _module_name(path):
  """'nerf_jax.cameras.rays' of .../nerf_jax/cameras/rays.py; a package's __init__.py is the
  package."""
  parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
  return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def module_imports(source, modules):
  """The modules of the set `modules` that `source` imports anywhere (inside functions too):
  `from a.b import c` is a.b.c where that is a module, else a.b."""
  found = set()
  for node in ast.walk(ast.parse(source)):
    if isinstance(node, ast.ImportFrom) and node.module and not node.level:
      found |= {f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules
                else node.module for a in node.names}
    elif isinstance(node, ast.Import):
      found |= {a.name for a in node.names}
  return found & modules


def import_graph():
  """{module: the nerf_jax modules it imports} over every module of nerf_jax/."""
  paths = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
  return {m: module_imports(p.read_text(), set(paths)) for m, p in paths.items()}


def find_cycle(graph):
  """A list [a, b, ..., a] of modules each importing the next, or None when there is none."""
  done, path = set(), []

  def visit(module):
    if module in path:
      return path[path.index(module):] + [module]
    if module in done:
      return None
    path.append(module)
    for target in sorted(graph.get(module, ())):
      cycle = visit(target)
      if cycle:
        return cycle
    path.pop()
    done.add(module)
    return None

  for module in sorted(graph):
    cycle = visit(module)
    if cycle:
      return cycle
  return None


def test_the_import_graph_is_read_as_python_resolves_it():
  modules = {"p", "p.a", "p.b", "p.c"}
  source = ("from p import a\nfrom p.b import thing\nimport p.c\nimport numpy\n"
            "def f():\n  from p.c import other\n")
  assert module_imports(source, modules) == {"p.a", "p.b", "p.c"}
  assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
  assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"b"}}) == ["b", "c", "b"]
  assert find_cycle({"a": {"a"}}) == ["a", "a"]
  graph = import_graph()
  assert "nerf_jax.cameras.rays" in graph["nerf_jax.cameras.cones"]
  assert "nerf_jax.backend.gpu_atomics" in graph["nerf_jax"]  # a package's __init__ counts


def test_no_import_circles():
  cycle = find_cycle(import_graph())
  assert cycle is None, "import circle: " + " -> ".join(cycle)
