"""docs/auto.md's table of auto's rules cannot drift from the code: its rows are the rules'
(`Rule.row`, in the order of rules.RULES); each threshold it quotes (`module.NAME = value`) is the
constant's value in its module (MODULES); every constant of the rules' modules, of
run/auto/auto.py and of run/auto/resolution.py is quoted; every line auto can print (the strings
those modules make into `auto:` lines, read from their source) appears in the table; and each
link in it reaches a page and one of its headings."""

import ast
import importlib
import pathlib
import pkgutil
import re

import pytest

from nerf_jax.run.auto import characterise
from nerf_jax.run.auto import rules as rules_package
from nerf_jax.run.auto.rules import RULES
from tests.helpers import ROOT

ROOT = pathlib.Path(ROOT)
PAGE = ROOT / "docs" / "auto.md"
RULE_MODULES = [m.name for m in pkgutil.iter_modules(rules_package.__path__)]
# The module each quoted `module.NAME` names.
MODULES = {"auto": "nerf_jax.run.auto.auto", "characterise": "nerf_jax.run.auto.characterise",
           "resolution": "nerf_jax.run.auto.resolution", "warm_up": "nerf_jax.run.auto.warm_up",
           "from_data": "nerf_jax.run.from_data",
           **{name: f"nerf_jax.run.auto.rules.{name}" for name in RULE_MODULES}}
AUTO = ROOT / "nerf_jax" / "run" / "auto"
SOURCES = {"auto": AUTO / "auto.py", "resolution": AUTO / "resolution.py",
           **{name: AUTO / "rules" / f"{name}.py" for name in RULE_MODULES}}
QUOTED = re.compile(r"`(\w+)\.([A-Z][A-Z0-9_]*) = ([^`]+)`")
# Functions that return a phrase or a value, not a line; and the regret benchmark's flips
# (functions named flip_*, _flip_*), whose reasons are not auto's lines.
NOT_LINES = {"cone_summary", "cone_effects", "has_cones", "_flat", "context_of"}
RECORDS = {"RULE", "RULES"}  # the records, not constants


def rules_table():
  """[{column: cell}] of the table under '## The rules' in docs/auto.md."""
  section = PAGE.read_text().split("\n## The rules\n", 1)[1].split("\n## ", 1)[0]
  rows = [line for line in section.splitlines() if line.startswith("|")]
  cells = lambda line: [c.strip() for c in line.strip().strip("|").split("|")]
  header = cells(rows[0])
  return [dict(zip(header, cells(row))) for row in rows[2:]]


def table_text():
  return "\n".join(" | ".join(row.values()) for row in rules_table())


def _literal_opening(node):
  """The phrase a line (a str constant or f-string node) begins with: its first run of literal
  text of 4 or more characters (after placeholders) up to its first ': ' or ' (' (where the
  reason or a field's name follows), stripped of spaces and the punctuation that joins it to a
  placeholder; None for a string of placeholders alone."""
  pieces = ([node.value] if isinstance(node, ast.Constant) else
            [v.value if isinstance(v, ast.Constant) else None for v in node.values])
  for piece in pieces:
    text = re.split(r": | \(", piece or "")[0].strip(" (<:;,")
    if len(text) >= 4:
      return text
  return None


def _strings(node):
  """The str constants and f-strings that `node` evaluates to (through lists, tuples and
  conditional expressions)."""
  if isinstance(node, ast.Constant) and isinstance(node.value, str) or isinstance(
      node, ast.JoinedStr):
    return [node]
  if isinstance(node, (ast.List, ast.Tuple)):
    return [s for e in node.elts for s in _strings(e)]
  if isinstance(node, ast.IfExp):
    return _strings(node.body) + _strings(node.orelse)
  if isinstance(node, ast.BinOp):  # "opening, " + a phrase
    return _strings(node.left)
  return []


def printed_openings():
  """The opening words of every line the SOURCES can print: the strings given to
  `lines.append` and the lines (all but the first element) of the tuples their functions
  return."""
  openings = set()
  for path in SOURCES.values():
    tree = ast.parse(path.read_text())
    for function in (n for n in tree.body if isinstance(n, ast.FunctionDef)):
      if function.name in NOT_LINES or function.name.lstrip("_").startswith("flip"):
        continue
      for node in ast.walk(function):
        found = []
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
            and node.func.attr == "append" and getattr(node.func.value, "id", "") == "lines"):
          found = _strings(node.args[0])
        elif isinstance(node, ast.Return) and isinstance(node.value, ast.Tuple):
          found = [s for e in node.value.elts[1:] for s in _strings(e)]
        openings.update(o for o in map(_literal_opening, found) if o)
  return openings


def test_the_rows_are_the_rules_in_their_order():
  assert [row["rule"] for row in rules_table()] == [rule.row for rule in RULES]
  assert len({rule.name for rule in RULES}) == len(RULES)
  # every rule module is in RULES, once
  assert sorted(rule.decide.__module__.rsplit(".", 1)[1] for rule in RULES) == sorted(
      RULE_MODULES)


def test_the_table_has_every_rule_of_the_issue():
  names = " ".join(row["rule"] for row in rules_table())
  for rule in ("photos' size", "background", "forward-facing", "unbounded", "contraction",
               "focus", "appearance codes", "view dependence", "cones", "subject box",
               "transients", "pose refinement", "backend", "large objects", "too few cameras",
               "depth from the tracks", "cameras refined"):
    assert rule in names


def test_every_quoted_threshold_is_the_codes():
  quoted = [m.groups() for row in rules_table() for m in QUOTED.finditer(row["threshold"])]
  assert len(quoted) >= 20
  for module, name, value in quoted:
    actual = getattr(importlib.import_module(MODULES[module]), name)
    assert ast.literal_eval(value) == actual, f"docs/auto.md: {module}.{name} = {value}"


def test_a_row_without_a_threshold_says_so():
  for row in rules_table():
    assert QUOTED.search(row["threshold"]) or row["threshold"] == "—", row["rule"]
    assert row["override"], row["rule"]


def _constants(path):
  """The upper-case names a module assigns at its top level (not the records, not private)."""
  tree = ast.parse(path.read_text())
  return {t.id for node in tree.body if isinstance(node, ast.Assign)
          for t in node.targets if isinstance(t, ast.Name) and t.id.isupper()
          and not t.id.startswith("_") and t.id not in RECORDS}


@pytest.mark.parametrize("module", sorted(SOURCES))
def test_every_constant_of_the_rules_is_quoted(module):
  quoted = {(m.group(1), m.group(2)) for row in rules_table()
            for m in QUOTED.finditer(row["threshold"])}
  assert {(module, c) for c in _constants(SOURCES[module])} <= quoted


def test_the_reader_finds_the_constants():
  constants = {m: _constants(path) for m, path in SOURCES.items()}
  assert {"MIN_STEPS"} <= constants["auto"] and {"MAX_SIDE"} <= constants["resolution"]
  assert {"DEPTH_WEIGHT", "DEPTH_MAX_VIEWS"} <= constants["depth"]


def test_every_line_auto_can_print_is_in_the_table():
  openings = printed_openings()
  # The reader above finds lines of every rule (a check on the reader itself).
  for known in ("no contraction", "transients left out", "backend gpu", "pose refinement",
                "from your flags, not auto's", "data.factor=1", "cameras are too few",
                "one scale", "no view dependence", "per-photo appearance codes",
                "cameras at several scales"):
    assert any(o.startswith(known) for o in openings), known
  text = table_text()
  missing = sorted(o for o in openings if o not in text)
  assert not missing, f"docs/auto.md's table lacks these auto: lines: {missing}"


def _slug(heading):
  """A heading's anchor as GitHub makes it."""
  return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_link_reaches_a_heading():
  links = re.findall(r"\]\(([^)#]+)#([^)]+)\)", PAGE.read_text())
  assert len(links) >= 10
  for page, anchor in links:
    headings = re.findall(r"^#+ (.+)$", (PAGE.parent / page).read_text(), re.MULTILINE)
    assert anchor in {_slug(h) for h in headings}, f"{page}#{anchor}"


def test_the_check_catches_a_changed_threshold(monkeypatch):
  monkeypatch.setattr(characterise, "FORWARD_CONE_DEGREES", 25.0)
  with pytest.raises(AssertionError, match="FORWARD_CONE_DEGREES"):
    test_every_quoted_threshold_is_the_codes()
