"""Every path and every `module.name` that README.md and docs/ name exists in this checkout, and
the public names users rely on stay importable with their signatures.

The docs are read as text: each `code span` and each markdown link target is one candidate.
  - a path (ends in a known extension, or a folder ending in '/') exists relative to the
    repository root, nerf_jax/, tests/ or the doc's own folder; a bare file name ('fast.py')
    exists somewhere in the repository;
  - a dotted name `nerf_jax.a.b` is a module, or a module and a name it defines;
  - `folder/module.name` (`run/builders.make_field`) names a module of nerf_jax/ and a name it
    defines; `module.name(` (`train_step.make_train_step(...)`) names a name some nerf_jax module
    of that name defines; `Class.attr` parts are checked as far as the class body.
Names are read from each module's source (its top-level definitions and imports, and a class's
own definitions), so nothing is imported but the public names at the end.
"""

import ast
import functools
import importlib
import inspect
import pathlib
import re

import pytest

from nerf_jax.run import config_lib
from tests.helpers import ROOT

ROOT = pathlib.Path(ROOT)
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
PACKAGE = ROOT / "nerf_jax"
EXTENSIONS = (".py", ".md", ".json", ".jsonl", ".png", ".toml", ".sh", ".txt", ".npz", ".npy")
# What the docs name that no checkout holds: other projects' files, a user's data and outputs.
ELSEWHERE = ("../", "~", "/usr/", "/tmp/", "runs/", "data/nerf", "data/mine", "configs/nerf/",
             "views/", "video/", "eval/", "checkpoints/", "http", "$", "scripts/", "internal/",
             "instant-ngp", "nerfstudio", "google/", "field_components/", "model_components/",
             "engine/", "models/", "src/", "lego/", "fern/", "fox/",
             "configs/llff/", "configs/flower.txt", "my_")  # my_*: the examples of yours
OUTPUTS = (".mp4", ".gif", ".msgpack")  # what runs write: named in the docs, never in a checkout
TOP = ("nerf_jax", "configs", "docs", "tests", ".ci")  # the repository's folders
FOLDERS = {p.name for p in ROOT.rglob("*") if p.is_dir() and ".git" not in p.parts}
SPAN = re.compile(r"`([^`\n]+)`")
LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")
DOTTED = re.compile(r"^[A-Za-z_][\w]*(?:\.[A-Za-z_]\w*)+(?:\(.*\))?$")
SLASHED = re.compile(r"^([a-z_]+(?:/[a-z_]+)*)/([a-z_]\w*)\.([A-Za-z_]\w*(?:\.\w+)*)(?:\(.*\))?$")


@functools.lru_cache(maxsize=None)
def defined_names(path, class_name=None):
  """Names a module's source defines at top level (or in `class_name`'s body). An old import
  path that replaces itself with another module (`sys.modules[__name__] = _module`) defines
  what that module defines."""
  source = pathlib.Path(path).read_text()
  tree = ast.parse(source)
  if "sys.modules[__name__] = _module" in source and class_name is None:
    target = _aliased_module(tree)
    if target is not None:
      return defined_names(target)
  body = tree.body
  if class_name:
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == class_name]
    if not classes:
      return frozenset()
    body = classes[0].body
  names = set()
  for node in body:
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
      names.add(node.name)
    elif isinstance(node, (ast.Assign, ast.AnnAssign)):
      targets = node.targets if isinstance(node, ast.Assign) else [node.target]
      for target in targets:
        names.update(n.id for n in ast.walk(target) if isinstance(n, ast.Name))
    elif isinstance(node, (ast.Import, ast.ImportFrom)):
      names.update((a.asname or a.name).split(".")[0] for a in node.names)
    if class_name and isinstance(node, ast.FunctionDef):  # self.x = ... in a method
      names.update(t.attr for t in ast.walk(node) if isinstance(t, ast.Attribute)
                   and isinstance(t.ctx, ast.Store) and isinstance(t.value, ast.Name)
                   and t.value.id == "self")
  return frozenset(names)


def _aliased_module(tree):
  """The file of `from nerf_jax.x import y as _module` in an old import path's source."""
  for node in tree.body:
    if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("nerf_jax"):
      for alias in node.names:
        if alias.asname == "_module":
          return module_file(node.module.split(".")[1:] + [alias.name])
  return None


@functools.lru_cache(maxsize=None)
def class_members(path):
  """Every name defined in the body of any class of a module (methods, properties, fields)."""
  tree = ast.parse(pathlib.Path(path).read_text())
  names = set()
  for node in tree.body:
    if isinstance(node, ast.ClassDef):
      names |= defined_names(path, node.name)
  return names


def module_file(parts):
  """The source file of module nerf_jax.<parts...> (a package's __init__.py), or None."""
  base = PACKAGE.joinpath(*parts)
  for candidate in (base.with_suffix(".py"), base / "__init__.py"):
    if candidate.is_file():
      return candidate
  if parts[:1] == ["configs"]:
    return module_file_in(ROOT.joinpath(*parts))
  return None


def module_file_in(base):
  for candidate in (base.with_suffix(".py"), base / "__init__.py"):
    if candidate.is_file():
      return candidate
  return None


def defines(path, attrs):
  """Whether module `path` defines attrs[0] (and, for a class, attrs[1] in its body)."""
  if not attrs:
    return True
  if attrs[0] not in defined_names(path):
    return False
  if len(attrs) > 1 and attrs[1] not in ("__call__",):
    classes = defined_names(path, attrs[0])
    return not classes or attrs[1] in classes or not _is_class(path, attrs[0])
  return True


def _is_class(path, name):
  tree = ast.parse(pathlib.Path(path).read_text())
  return any(isinstance(n, ast.ClassDef) and n.name == name for n in tree.body)


@functools.lru_cache(maxsize=None)
def modules_named(name):
  return tuple(p for p in PACKAGE.rglob(f"{name}.py"))


@functools.lru_cache(maxsize=None)
def config_sections():
  """{section: its field names} of configs/default.py (`occupancy.enabled` is a field)."""
  sections = {}

  def visit(name, node):
    sections.setdefault(name, set()).update(node.keys())
    for key, value in node.items():
      if hasattr(value, "keys"):
        visit(key, value)

  visit("config", config_lib.default())
  return sections


def problem_with(token, doc):
  """Why `token` (a code span or link target of `doc`) names nothing in this checkout, or None."""
  token = token.strip().rstrip(".,;:")
  if " " in token or any(c in token for c in "<>{}*…|=,'\"") or "XXX" in token:
    return None
  if token.startswith(ELSEWHERE) or any(part in token for part in ("://",)):
    return None
  if token.endswith(OUTPUTS):  # a file a run writes (depth.mp4), not a module's name
    return None
  if token.endswith(EXTENSIONS) or (token.endswith("/") and "/" in token[:-1]):
    return _path_problem(token, doc)
  slashed = SLASHED.match(token)
  if slashed:
    folder, module, attrs = slashed.groups()
    folder = folder[len("nerf_jax/"):] if folder.startswith("nerf_jax/") else folder
    path = module_file(folder.split("/") + [module]) if folder != "nerf_jax" else module_file([module])
    if path is None:
      return f"no module nerf_jax/{folder}/{module}.py"
    if defines(path, attrs.split(".")):
      return None
    return f"{path.relative_to(ROOT)} defines no {attrs}"
  if DOTTED.match(token):
    return _dotted_problem(token.split("(")[0])
  return None


def _path_problem(token, doc):
  """A path from the repository's top (nerf_jax/, configs/, docs/, tests/) must exist there
  or beside the doc; a shorter one (`scenes/photos.py`, `fast.py`) must end some file's path of
  the repository. Names of the user's or other projects' files (`OUT/images/`,
  `transforms.json`) are not checked: only ours, the .py and .md files and our folders."""
  clean = token.rstrip("/")
  first = clean.split("/")[0]
  if first in TOP or (doc.parent / token).exists():
    return None if (ROOT / token).exists() or (doc.parent / token).exists() else "no such path"
  if not (clean.endswith(".py") or ("/" in clean and clean.endswith(".md"))
          or token.endswith("/")):
    return None  # a bare name of a data or output file (check.md, transforms.json)
  if "/" in clean and first not in FOLDERS:
    return None  # a folder of the user's (OUT/images/) or of another project
  if token.endswith("/"):
    return None if any(p.is_dir() and p.as_posix().endswith("/" + clean)
                       for p in ROOT.rglob(clean.split("/")[-1])) else "no such folder"
  found = any(p.as_posix().endswith("/" + clean) for p in ROOT.rglob(clean.split("/")[-1]))
  return None if found else "no such path"


def _dotted_problem(name):
  parts = name.split(".")
  if parts[0] == "nerf_jax":
    for cut in range(len(parts), 1, -1):
      path = module_file(parts[1:cut])
      if path is not None:
        if defines(path, parts[cut:]):
          return None
        return f"{path.relative_to(ROOT)} defines no {'.'.join(parts[cut:])}"
    return f"no module {'.'.join(parts[:2])}"
  if name in config_lib.RENAMED:
    return None  # an old spelling of a config field, still read (config_lib.upgrade)
  sections = config_sections()
  if parts[0] in sections and (len(parts) < 2 or parts[1] in sections[parts[0]]):
    return None  # a config field (occupancy.enabled), not a module's name
  found = modules_named(parts[0])
  if not found or len(parts) < 2:
    return None  # not one of ours (jax.jit, np.asarray, config.train.lr)
  if any(defines(path, parts[1:]) for path in found):
    return None
  if any(parts[1] in class_members(path) for path in found):
    return None  # `state.variables`: an attribute of an instance of the module's class
  return f"no nerf_jax module {parts[0]}.py defines {'.'.join(parts[1:])}"


def named_in(doc):
  text = doc.read_text()
  return [(m.group(1), doc) for m in SPAN.finditer(text)] + [
      (m.group(1), doc) for m in LINK.finditer(text)]


def test_every_path_and_name_in_the_docs_exists():
  problems = []
  for doc in DOCS:
    for token, where in named_in(doc):
      why = problem_with(token, where)
      if why:
        problems.append(f"{doc.relative_to(ROOT)}: `{token}`: {why}")
  assert not problems, "\n".join(sorted(set(problems)))


@pytest.mark.parametrize("token", ["nerf_jax/no_such_module.py", "nerf_jax.run.no_such_module",
                                   "nerf_jax.cameras.rays.no_such_function",
                                   "run/builders.no_such_builder",
                                   "train_step.no_such_function(x)"])
def test_the_check_catches_a_wrong_name(token):
  assert problem_with(token, ROOT / "README.md")


@pytest.mark.parametrize("token", ["nerf_jax/cameras/rays.py", "nerf_jax.cameras.rays.get_rays",
                                   "nerf_jax.bench", "occupancy.enabled", "fast.py",
                                   "tests/topics/"])
def test_the_check_passes_a_right_name(token):
  assert problem_with(token, ROOT / "README.md") is None


# The public names users rely on (the brief and README.md): how many positional parameters they
# take without a default (get_rays(H, W, focal, c2w), composite(rgb, sigma, t_edges)), and the
# keyword parameters with the default they must keep.
PUBLIC = {
    "nerf_jax.rays.get_rays": (4, {}),
    "nerf_jax.rendering.composite": (3, {"background": None}),
    "nerf_jax.encoding.positional_encoding": (2, {}),
    "nerf_jax.sampling.sample_pdf": (None, {}),  # importable; its parameters are its docstring's
}


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_public_names_stay_importable_with_their_signatures(name):
  module, _, attr = name.rpartition(".")
  fn = getattr(importlib.import_module(module), attr)
  assert callable(fn)
  required, keywords = PUBLIC[name]
  params = inspect.signature(fn).parameters.values()
  if required is not None:
    positional = [p for p in params if p.default is inspect.Parameter.empty]
    assert len(positional) == required, list(inspect.signature(fn).parameters)
  for keyword, default in keywords.items():
    assert inspect.signature(fn).parameters[keyword].default == default


SOURCE_PATH = re.compile(r"(?<![\w/.])nerf_jax/[\w/]+\.py")


def test_every_nerf_jax_path_in_a_comment_or_docstring_exists():
  """Comments and docstrings of the package, configs and tests name files as nerf_jax/x/y.py:
  each must exist (a module moved without its mentions sends readers nowhere)."""
  sources = [*PACKAGE.rglob("*.py"), *(ROOT / "configs").rglob("*.py"),
             *(ROOT / "tests").rglob("*.py"), ROOT / "train.py", ROOT / "render.py"]
  missing = sorted({f"{source.relative_to(ROOT)}: {path}" for source in sources
                    if source != pathlib.Path(__file__)
                    for path in SOURCE_PATH.findall(source.read_text())
                    if not (ROOT / path).exists()})
  assert not missing, "\n".join(missing)
