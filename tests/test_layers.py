"""The layering rule: no ConfigDict is read below the entry layer.

Outside the entry modules (cli, config_lib, experiment, auto, train*, outputs*, eval*, bench/,
viewer/, data/loaders.py) no function takes a `config` / `*_config` argument and no code reads a
`config.` / `*_config.` attribute: each layer receives its own small, typed settings, built once
by experiment.py. Checked on the syntax tree (docstrings and messages may name config fields).
"""

import ast
import pathlib
import re

import nerf_jax

PACKAGE = pathlib.Path(nerf_jax.__file__).parent
ENTRY = re.compile(r"^(cli|config_lib|experiment|auto|train\w*|outputs\w*|eval\w*)\.py$|"
                   r"^(bench|viewer)/|^data/loaders\.py$")
CONFIG_NAME = re.compile(r"^(config|\w+_config)$")


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
  assert len(files) > 30 and any(f.name == "renderer.py" for f in files)
  uses = [f"{f.relative_to(PACKAGE)}:{line}: {what}" for f in files
          for line, what in config_uses(f.read_text())]
  assert not uses, "\n".join(uses)
