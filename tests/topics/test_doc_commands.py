"""Every command in README.md and docs/*.md works as written: checked by parsing, not running.

A command is a line of a fenced block (```, ```bash, ```sh, ```console, ```text; a ```python block
is code, not a shell) that runs `python`, `python3` or one of pyproject's console scripts, first
(after an optional `$ ` prompt and `NAME=VALUE` environment) or after `&&` or `;`:
backslash-continued lines are joined, `&&`, `;` and `|` separate commands, `# ...` is a
comment, and `NAME="..."` lines of the same block are expanded where `$NAME` is used. Every
other line of a block is a program's output, or a command of no interest here, and is skipped.

For each command:
  - the script (`python render.py`), module (`python -m nerf_jax.bench`) or console script
    exists; another project's module (pip, venv, pytest) only has to be installed, and pytest's
    files have to exist;
  - the entry point parses the command's flags with its own definitions, in a fresh process as a
    shell would start it: absl's `app.run` and argparse's `parse_args` parse and stop there, so
    nothing trains. An undefined flag, a bad value, an unknown `--config.a.b` override or one
    whose value does not parse to the field's type, or a stray positional argument fails;
  - `--config=NAME` names a shipped config (configs/, not a file of the user's), and no
    override uses a field's old spelling (config_lib.RENAMED).
Paths given as values (DIR, runs/x) are not looked for: they are the reader's.

A script that parses neither with absl nor with argparse (docs/nerfacto/score_views.py reads
sys.argv) is never run: it must exist and be given no flags.
"""

import argparse
import contextlib
import dataclasses
import importlib.util
import io
import json
import os
import pathlib
import re
import runpy
import shlex
import subprocess
import sys
import tomllib
from unittest import mock

import pytest
from absl import app, flags

from nerf_jax import cli
from nerf_jax.run import config_lib
from tests.helpers import ROOT

ROOT = pathlib.Path(ROOT)
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL_BLOCKS = ("", "bash", "sh", "shell", "console", "text")
PYTHONS = ("python", "python3")
with open(ROOT / "pyproject.toml", "rb") as _f:
  SCRIPTS = tomllib.load(_f)["project"]["scripts"]  # console script -> "module:function"
# Other projects' modules the docs run: they need only be installed.
EXTERNAL = ("pip", "venv", "pytest")
FENCE = re.compile(r"^\s*```\s*(\w*)")
ASSIGNMENT = re.compile(r"^([A-Z_][A-Z0-9_]*)=(.*)$")
VARIABLE = re.compile(r"\$\{?([A-Z_][A-Z0-9_]*)\}?")
# A line that runs a command of interest, first or after `&&` / `;`.
STARTS = re.compile(r"(?:^|&&|;)\s*(?:%s)(?:\s|$)"
                    % "|".join(map(re.escape, (*PYTHONS, *SCRIPTS))))


@dataclasses.dataclass(frozen=True)
class Command:
  doc: str    # the page, relative to the repository root
  line: int   # its first line in the page (1-based)
  argv: tuple  # the words, program first

  @property
  def id(self):
    return f"{self.doc}:{self.line}"


def _logical_lines(block):
  """(line number, text) of a block's lines (list of (number, text)) with backslash-continued
  lines joined."""
  out, start, parts = [], None, []
  for number, text in block:
    if start is None:
      start = number
    if text.rstrip().endswith("\\"):
      parts.append(text.rstrip()[:-1])
      continue
    parts.append(text)
    out.append((start, " ".join(p.strip() for p in parts)))
    start, parts = None, []
  if parts:
    out.append((start, " ".join(p.strip() for p in parts)))
  return out


def _words(text):
  """The commands of one shell line: lists of words, split at &&, ;, | and a # comment."""
  lexer = shlex.shlex(text, posix=True, punctuation_chars=True)
  lexer.whitespace_split = True
  commands, current = [], []
  for word in lexer:
    if word in ("&&", ";", "|", "||", "&"):
      commands.append(current)
      current = []
    else:
      current.append(word)
  return [c for c in commands + [current] if c]


def _is_command(words):
  return words[0] in PYTHONS or words[0] in SCRIPTS


def block_commands(doc, block):
  """The Commands of one fenced block (list of (line number, text)) of page `doc`."""
  variables, commands = {}, []
  for number, text in _logical_lines(block):
    text = text.strip()
    text = text[2:] if text.startswith("$ ") else text
    if ASSIGNMENT.match(text):  # NAME=VALUE: a variable, or the environment of a command
      words = shlex.split(text, comments=True)
      environment = words[:next((i for i, w in enumerate(words) if not ASSIGNMENT.match(w)),
                                len(words))]
      if len(environment) == len(words):
        variables.update(w.split("=", 1) for w in words)
        continue
      text = shlex.join(words[len(environment):])
    if not STARTS.search(text):
      continue  # a program's output, or a command of no interest (cd, bash)
    text = VARIABLE.sub(lambda m: variables.get(m.group(1), m.group(0)), text)
    commands += [Command(doc, number, tuple(w)) for w in _words(text) if _is_command(w)]
  return commands


def doc_commands(path):
  """Every Command in the shell blocks of the page at `path`."""
  doc = str(pathlib.Path(path).relative_to(ROOT))
  commands, block, language = [], None, None
  for number, text in enumerate(pathlib.Path(path).read_text().splitlines(), 1):
    fence = FENCE.match(text)
    if fence and block is None:
      block, language = [], fence.group(1)
    elif fence:
      if language in SHELL_BLOCKS:
        commands += block_commands(doc, block)
      block = None
    elif block is not None:
      block.append((number, text))
  return commands


COMMANDS = [c for doc in DOCS for c in doc_commands(doc)]


def entry(argv):
  """What a command runs: ('script', path), ('module', name), ('console', 'module:function')
  or ('external', module name); and the arguments it is given."""
  if argv[0] in SCRIPTS:
    return ("console", SCRIPTS[argv[0]]), list(argv[1:])
  if len(argv) > 2 and argv[1] == "-m":
    kind = "external" if argv[2].split(".")[0] in EXTERNAL else "module"
    return (kind, argv[2]), list(argv[3:])
  if len(argv) > 1 and argv[1].endswith(".py"):
    return ("script", argv[1]), list(argv[2:])
  return ("unknown", " ".join(argv[:2])), list(argv[2:])


def static_problems(command):
  """What can be said of `command` without importing it: a missing script or module, a config
  that is not shipped, an old spelling."""
  (kind, target), args = entry(command.argv)
  problems = []
  if kind == "unknown":
    problems.append(f"{target}: neither a script, `-m MODULE` nor a console script")
  if kind == "script" and not (ROOT / target).is_file():
    problems.append(f"{target}: no such script")
  if kind in ("module", "console"):
    module = target.split(":")[0]
    path = ROOT / module.replace(".", "/")
    if not (path.with_suffix(".py").is_file() or (path / "__main__.py").is_file()
            or (kind == "console" and (path / "__init__.py").is_file())):
      problems.append(f"{module}: no such module in this checkout")
  if kind == "external" and importlib.util.find_spec(target.split(".")[0]) is None:
    problems.append(f"{target}: not installed")
  if kind == "external" and target == "pytest":
    problems += [f"{a}: no such test path" for a in args
                 if not a.startswith("-") and not (ROOT / a.split("::")[0]).exists()]
  for arg in args:
    if arg.startswith("--config=") and kind != "external":
      spec = arg.split("=", 1)[1].split(":")[0]
      try:
        path = config_lib.resolve(spec)
      except config_lib.ConfigError as e:
        problems.append(str(e))
        continue
      if not os.path.realpath(path).startswith(os.path.realpath(ROOT / "configs") + os.sep):
        problems.append(f"{arg}: not a shipped config (configs/)")
    if arg.startswith("--config."):
      field = arg[len("--config."):].split("=", 1)[0]
      if config_lib.renamed(field) != field:
        problems.append(f"{arg}: an old spelling of --config.{config_lib.renamed(field)}")
  return problems


# -- What runs in the fresh process: each entry point parses its command's flags and stops. ------


class _Parsed(Exception):
  """Raised where the entry point would start its work: its flags parsed."""


def parse_as_entry(command):
  """None if `command`'s entry point accepts its flags, else what it said. Runs the entry point
  as its command line would, with absl's app.run and argparse's parse_args stopping after the
  parse; the flags it defined are removed again afterwards."""
  (kind, target), args = entry(command.argv)
  if kind == "script":
    source = (ROOT / target).read_text()
    if "sys.argv[" in source and "app.run" not in source and "argparse" not in source:
      flagged = [a for a in args if a.startswith("-")]
      return f"{target} reads sys.argv, not flags: {flagged}" if flagged else None
    run = lambda: runpy.run_path(str(ROOT / target), run_name="__main__")  # noqa: E731
  elif kind == "module":
    run = lambda: runpy.run_module(target, run_name="__main__", alter_sys=True)  # noqa: E731
  else:
    module, function = target.split(":")
    run = lambda: getattr(__import__(module, fromlist=[function]), function)()  # noqa: E731

  before, parse_args = set(flags.FLAGS), argparse.ArgumentParser.parse_args

  def app_run(main, argv=None, flags_parser=None):  # pylint: disable=unused-argument
    rest = flags.FLAGS(list(sys.argv if argv is None else argv))
    if len(rest) > 1:
      raise flags.Error(f"unexpected positional argument {rest[1]!r}")
    raise _Parsed

  def argparse_parse(self, args=None, namespace=None):
    parse_args(self, args, namespace)
    raise _Parsed

  stderr = io.StringIO()
  argv = [command.argv[0] if kind == "console" else target, *args]
  try:
    with mock.patch.object(app, "run", app_run), \
         mock.patch.object(argparse.ArgumentParser, "parse_args", argparse_parse), \
         mock.patch.object(sys, "argv", argv), contextlib.redirect_stderr(stderr):
      run()
    return "the entry point never reached its flag parsing"
  except _Parsed:
    return None
  except SystemExit as e:
    return f"exit status {e.code}: {stderr.getvalue().strip()}"
  except flags.Error as e:
    return f"{type(e).__name__}: {e}"
  finally:
    flags.FLAGS.unparse_flags()
    for name in set(flags.FLAGS) - before:
      delattr(flags.FLAGS, name)


def parse_all(commands):
  """{command id: problem or None} of parse_as_entry over `commands`."""
  return {c.id: parse_as_entry(c) for c in commands
          if entry(c.argv)[0][0] in ("script", "module", "console")}


def parse_in_fresh_process(commands):
  """parse_all(commands) in a fresh Python process, as a shell starts each command (no flag or
  module of this one in its way)."""
  code = ("import json, sys; from tests.topics import test_doc_commands as t; "
          "cs = [t.Command(d, n, tuple(a)) for d, n, a in json.load(sys.stdin)]; "
          "print('RESULT' + json.dumps(t.parse_all(cs)))")
  env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(ROOT)}
  given = json.dumps([[c.doc, c.line, list(c.argv)] for c in commands])
  out = subprocess.run([sys.executable, "-c", code], input=given, cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=600, check=False)
  lines = [l for l in out.stdout.splitlines() if l.startswith("RESULT")]
  assert lines, out.stderr[-3000:]
  return json.loads(lines[-1][len("RESULT"):])


@pytest.fixture(scope="module")
def parsed():
  """{command id: problem or None} of every doc command's parse (parse_in_fresh_process)."""
  return parse_in_fresh_process(COMMANDS)


def test_the_docs_have_commands():
  docs = {c.doc for c in COMMANDS}
  assert len(COMMANDS) > 50 and "README.md" in docs, sorted(docs)


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c.id)
def test_doc_command(command, parsed):
  problems = static_problems(command)
  if parsed.get(command.id):
    problems.append(parsed[command.id])
  assert not problems, f"{command.id}: {shlex.join(command.argv)}\n  " + "\n  ".join(problems)


def _flag(args, name):
  """The value of --name=VALUE in args (None if absent)."""
  values = [a.split("=", 1)[1] for a in args if a.startswith(f"--{name}=")]
  return values[-1] if values else None


def written_workdir(command):
  """The workdir a training command writes: its --workdir, else cli.default_workdir of its
  config with its data overrides. None if `command` does not train."""
  (_, target), args = entry(command.argv)
  if target not in ("train.py", SCRIPTS["nerf-train"]):
    return None
  if _flag(args, "workdir"):
    return _flag(args, "workdir")
  spec = _flag(args, "config") or ""
  config = config_lib.load(spec or "default")
  for field in ("data.path", "data.scene"):
    if _flag(args, f"config.{field}") is not None:
      config_lib.set_field(config, field, _flag(args, f"config.{field}"))
  return cli.default_workdir(config, spec)


READERS = ("render.py", SCRIPTS["nerf-render"], SCRIPTS["nerf-view"], "nerf_jax.viewer",
           "nerf_jax.bench.render")


def test_the_readme_renders_and_views_what_it_trains():
  """Each workdir the README renders or views is one a training command of the README writes
  (`python train.py` alone: runs/default_diffuse)."""
  commands = doc_commands(ROOT / "README.md")
  written = {written_workdir(c) for c in commands} - {None}
  read = [(c.id, _flag(entry(c.argv)[1], "workdir")) for c in commands
          if entry(c.argv)[0][1] in READERS]
  assert read and "runs/default_diffuse" in written, (read, written)
  assert [r for r in read if r[1] not in written] == [], written


def test_the_readme_is_a_door_not_the_house():
  assert (ROOT / "README.md").stat().st_size < 12_000


# -- The extraction and the check themselves. -----------------------------------------------------


def test_a_block_is_read_as_a_shell_would():
  block = list(enumerate([
      'FOX="--config=capture --config.data.factor=4"',
      "$ python train.py $FOX --workdir=runs/fox \\",
      "    --config.num_samples=32   # a comment",
      "step 100: loss 0.01 (output)",
      'pip install -e . && python -m nerf_jax.bench --only=a,"b c"',
      "JAX_DEBUG_NANS=True python train.py --config=fast   # the environment, then the command",
  ], 1))
  assert [(c.line, c.argv) for c in block_commands("x.md", block)] == [
      (2, ("python", "train.py", "--config=capture", "--config.data.factor=4",
           "--workdir=runs/fox", "--config.num_samples=32")),
      (5, ("python", "-m", "nerf_jax.bench", "--only=a,b c")),
      (6, ("python", "train.py", "--config=fast"))]


@pytest.mark.parametrize("argv", [
    ("python", "train.py", "--config=nonexistent"),
    ("python", "train.py", "--config=README.md"),
    ("python", "nonexistent.py"),
    ("python", "-m", "nerf_jax.nonexistent"),
    ("python", "train.py", "--config.model.grid_features=4"),
    ("python", "-m", "pytest", "tests/nonexistent.py"),
])
def test_the_static_check_catches(argv):
  assert static_problems(Command("x.md", 1, argv))


def test_the_static_check_passes_a_right_command():
  argv = ("python", "train.py", "--config=scenes/fog", "--config.model.grid.features=4")
  assert not static_problems(Command("x.md", 1, argv))


@pytest.mark.slow
def test_the_parse_catches_and_passes():
  """In a fresh process, as the docs' commands are parsed: a good command of each kind passes,
  a bad flag, override, value or positional argument fails."""
  good = [("python", "train.py", "--config=fast", "--config.train.batch_rays=2048"),
          ("python", "render.py", "--workdir=w", "--mode=mesh", "--resolution=64"),
          ("nerf-process", "--images=p", "--out=o"),
          ("python", "-m", "nerf_jax.bench", "--sweep=samples", "--config=mlp64",
           "--config.train.batch_rays=2048"),
          ("python", "-m", "nerf_jax.data.export", "--scene=white", "--format=npz", "--out=w")]
  bad = [("python", "train.py", "--no_such_flag=1"),
         ("python", "train.py", "--config.train.no_such_field=1"),
         ("python", "train.py", "--config.train.batch_rays=many"),
         ("python", "render.py", "--workdir=w", "--mode=nonsense"),
         ("python", "render.py", "--workdir=w", "extra"),
         ("python", "-m", "nerf_jax.data.export", "--no_such_flag"),
         ("python", "-m", "nerf_jax.bench", "--budget_seconds=soon")]
  commands = [Command("x.md", i, a) for i, a in enumerate(good + bad)]
  result = parse_in_fresh_process(commands)
  assert [result[c.id] for c in commands[:len(good)]] == [None] * len(good)
  assert all(result[c.id] for c in commands[len(good):]), result
