"""docs/auto.md's table of auto's rules cannot drift from the code: each threshold it quotes
(`module.NAME = value`) is the constant's value in nerf_jax/run/<module>.py; every constant of
run/auto.py and run/resolution.py is quoted; every line auto can print (the strings that
run/auto.py and run/resolution.py make into `auto:` lines, read from their source) appears in
the table; and each link in it reaches a page and one of its headings."""

import ast
import importlib
import pathlib
import re

import pytest

from nerf_jax.run import characterise
from tests.helpers import ROOT

ROOT = pathlib.Path(ROOT)
PAGE = ROOT / "docs" / "auto.md"
SOURCES = [ROOT / "nerf_jax" / "run" / "auto.py", ROOT / "nerf_jax" / "run" / "resolution.py"]
QUOTED = re.compile(r"`(\w+)\.([A-Z][A-Z0-9_]*) = ([^`]+)`")
# Functions of run/auto.py that return a phrase or a value, not a line.
NOT_LINES = {"cone_summary", "cone_effects", "_flat"}


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
  """The opening words of every line run/auto.py and run/resolution.py can print: the strings
  given to `lines.append`, the lines (all but the first element) of the tuples their functions
  return, the rule settings' phrases (`settings`) and their absences ('no <rule>', `absent`)."""
  openings = set()
  for path in SOURCES:
    tree = ast.parse(path.read_text())
    for function in (n for n in tree.body if isinstance(n, ast.FunctionDef)):
      if function.name in NOT_LINES:
        continue
      for node in ast.walk(function):
        found = []
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
            and node.func.attr == "append" and getattr(node.func.value, "id", "") == "lines"):
          found = _strings(node.args[0])
        elif isinstance(node, ast.Return) and isinstance(node.value, ast.Tuple):
          found = [s for e in node.value.elts[1:] for s in _strings(e)]
        elif isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "settings":
          keys = [k.value for k in node.value.keys]
          found = [s for v in node.value.values for s in _strings(v)]
          openings.update("one scale" if k == "scales" else "no " + k.replace("_", " ")
                          for k in keys)  # `absent` in auto_config
        openings.update(o for o in map(_literal_opening, found) if o)
  return openings


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
    actual = getattr(importlib.import_module(f"nerf_jax.run.{module}"), name)
    assert ast.literal_eval(value) == actual, f"docs/auto.md: {module}.{name} = {value}"


def test_a_row_without_a_threshold_says_so():
  for row in rules_table():
    assert QUOTED.search(row["threshold"]) or row["threshold"] == "—", row["rule"]
    assert row["override"], row["rule"]


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: p.name)
def test_every_constant_of_the_rules_is_quoted(path):
  quoted = {(m.group(1), m.group(2)) for row in rules_table()
            for m in QUOTED.finditer(row["threshold"])}
  tree = ast.parse(path.read_text())
  constants = {t.id for node in tree.body if isinstance(node, ast.Assign)
               for t in node.targets if isinstance(t, ast.Name) and t.id.isupper()
               and not t.id.startswith("_")}
  assert constants
  assert {(path.stem, c) for c in constants} <= quoted


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
