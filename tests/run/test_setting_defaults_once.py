"""A setting's default lives in its settings dataclass alone: no runtime part (a function's or a
constructor's parameter, a dataclass's or Flax module's field) named as a setting restates that
setting's default as a literal. It takes it from the dataclass (`Settings.name`) or has none (its
callers pass the setting), so changing a default changes it everywhere."""

import ast
import dataclasses
import pathlib

from nerf_jax.backend import components
from nerf_jax.run import config_lib
from tests.helpers import ROOT

PACKAGE = pathlib.Path(ROOT) / "nerf_jax"
# Not runtime parts of a run: the benchmarks' own knobs, and the built-in scenes' generation
# parameters (a scene's seed or size is the scene's, not config.seed or data.image_size).
SKIPPED = ("bench/", "data/scenes/")
# Parameters named as a setting whose literal default is their own, not the setting's (each
# equal to it by chance): {(file, owner.parameter): why}.
OWN_DEFAULTS = {
    ("data/dataset.py", "split.holdout_from"):
        "-1: the reference's split (the first 80%), not data.holdout_from's 'the format's own'",
    ("fields/encodings/hash.py", "encode.dtype"):
        "the lattice's compute dtype: the proposal's density fields use float32 whatever "
        "model.dtype says",
    ("render/renderer.py", "RayRenderer.sample_budget"):
        "0: renders query every slot; training replaces it with train.sample_budget",
    ("run/auto/characterise.py", "highlight_excess.seed"):
        "auto's measurement, repeatable whatever the run's config.seed",
    ("run/auto/warm_up.py", "warm_up_config.seed"):
        "auto's warm-up, repeatable whatever the run's config.seed",
    ("run/auto/warm_up.py", "photos_and_renders.seed"):
        "auto's warm-up, repeatable whatever the run's config.seed",
    ("samplers/spacing.py", "stratified.lindisp"):
        "linear spacing: the occupancy grid's candidates take it whatever data.lindisp says",
    ("samplers/spacing.py", "sample_pdf.padding"):
        "NeRF's fine pass's padding, not the proposal sampler's (config.proposal.padding)",
}


def setting_defaults():
  """{setting name: [its default in each settings dataclass declaring one of that name]}, and
  the set of those dataclasses' names (their fields are the declarations)."""
  defaults, classes = {}, set()
  for section in config_lib.SECTIONS.values():
    for cls in section:
      classes.add(cls.__name__)
      for field in components.settings_fields(cls):
        value = (field.default if field.default is not dataclasses.MISSING
                 else field.default_factory())
        defaults.setdefault(field.name, []).append(value)
  return defaults, classes


def _literal(node):
  """The value of a literal default (a constant, a tuple of them, -1); None where it names
  something (`Settings.chunk`, jnp.float32) or computes it. (found, value)."""
  if node is None:
    return False, None
  if isinstance(node, ast.Call):  # dataclasses.field(default=...), flax.struct.field(...)
    node = next((k.value for k in node.keywords if k.arg == "default"), None)
    return _literal(node)
  try:
    return True, ast.literal_eval(node)
  except ValueError:
    return False, None


def _same(a, b):
  """Equal and of one type (True is not 1, 0 is not 0.0 or False)."""
  return type(a) is type(b) and a == b


def restated(source, defaults, settings_classes=()):
  """[(owner.parameter, line)] of the parameters and fields in `source` (Python text) named
  as a setting of `defaults` ({name: [default, ...]}) whose literal default equals one of that
  setting's; the fields of the classes named in `settings_classes` are declarations, not
  repeats."""
  found = []
  def check(owner, name, node):
    is_literal, value = _literal(node)
    if is_literal and any(_same(value, d) for d in defaults.get(name, ())):
      found.append((f"{owner}.{name}", node.lineno))
  for node in ast.walk(ast.parse(source)):
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
      args = node.args
      positional = args.posonlyargs + args.args
      for arg, default in zip(positional[len(positional) - len(args.defaults):], args.defaults):
        check(node.name, arg.arg, default)
      for arg, default in zip(args.kwonlyargs, args.kw_defaults):
        check(node.name, arg.arg, default)
    elif isinstance(node, ast.ClassDef) and node.name not in settings_classes:
      for statement in node.body:
        if isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name):
          check(node.name, statement.target.id, statement.value)
  return found


def _package_repeats():
  """{(file, owner.parameter): line} of every restated default in the package's runtime."""
  defaults, classes = setting_defaults()
  repeats = {}
  for path in sorted(PACKAGE.rglob("*.py")):
    name = path.relative_to(PACKAGE).as_posix()
    if not name.startswith(SKIPPED):
      for where, line in restated(path.read_text(), defaults, classes):
        repeats[(name, where)] = line
  return repeats


def test_no_runtime_part_restates_a_settings_default():
  repeats = _package_repeats()
  unexplained = {k: v for k, v in repeats.items() if k not in OWN_DEFAULTS}
  assert not unexplained, (
      "these restate a setting's default: take it from the settings dataclass "
      f"(Settings.name) or drop it: {unexplained}")
  # Every exception is still there (a stale one would excuse a future repeat unread).
  assert set(OWN_DEFAULTS) <= set(repeats)


def test_the_reader_finds_a_restated_default_and_nothing_else():
  defaults = {"chunk": [4096], "contraction": [""], "lindisp": [False], "seed": [0]}
  source = '''
def render_image(rays, chunk=4096): ...
def shade(rays, chunk=ImageSettings.chunk): ...
def other(rays, chunk=1024, lindisp=0, seed=0.0): ...
def keyword_only(rays, *, contraction=""): ...
class Sampler:
  contraction: str = ""
  lindisp: bool = SceneSettings.lindisp
  seed: int = dataclasses.field(default=0)
class Settings:
  chunk: int = 4096  # the declaration itself
'''
  assert sorted(restated(source, defaults, {"Settings"})) == [
      ("Sampler.contraction", 7), ("Sampler.seed", 9), ("keyword_only.contraction", 5),
      ("render_image.chunk", 2)]


def test_the_settings_are_read_whole():
  defaults, classes = setting_defaults()
  assert {"SceneSettings", "DataSettings", "ImageSettings", "OccupancySettings"} <= classes
  assert defaults["chunk"] == [4096] and "" in defaults["contraction"]
  assert len(defaults) > 150
