"""docs/extending.md's auto-rule walk-through, run as written: its rule module is written into a
temporary folder and imported as the rules package's module orbit would be, put in RULES where
the text says (before the step rule), the doc's test for it runs, and the doc's table row is
checked against the module as tests/topics/test_auto_doc.py checks docs/auto.md's rows; no file
of the tree is touched."""

import ast

import pytest

from nerf_jax.run import config_lib
from nerf_jax.run.auto import auto
from nerf_jax.run.auto import rules as rules_package
from nerf_jax.run.auto.rules import step_rule
from tests import helpers
from tests.topics import test_auto_doc

THIS = "tests/topics/test_extending_auto_rule.py"
NAME = "nerf_jax.run.auto.rules.orbit"


def _row_block():
  """The doc's ```markdown block marked 'row': one table row."""
  return helpers.doc_block("docs/extending.md", THIS, "row", "markdown").strip()


@pytest.fixture
def orbit(tmp_path, monkeypatch):
  """The doc's module, imported as rules/orbit.py, its RULE in RULES before the step rule's."""
  module, path = helpers.import_doc_module(tmp_path, monkeypatch, THIS, NAME, rules_package)
  rules = list(rules_package.RULES)
  rules.insert(rules.index(step_rule.RULE), module.RULE)
  monkeypatch.setattr(rules_package, "RULES", tuple(rules))
  return module, path


def test_the_docs_test_of_the_rule_passes(orbit):
  namespace = {"__name__": "test_auto_orbit"}
  exec(compile(helpers.doc_block("docs/extending.md", THIS, "test"), "test_auto_orbit.py",
               "exec"), namespace)  # pylint: disable=exec-used
  tests = [f for name, f in namespace.items() if name.startswith("test_")]
  assert len(tests) == 3
  for test in tests:
    test()


def test_the_rules_line_prints_where_the_text_says(orbit):
  module, _ = orbit
  config = config_lib.load("auto")
  config.data.scene, config.data.image_size, config.data.num_views = "forward", 16, 12
  decided = auto.auto_config(config, helpers.load_data(config.data)[0], backend="cpu",
                             rules=rules_package.RULES)
  lines = list(decided.auto_decisions)
  at = next(i for i, l in enumerate(lines) if l.startswith("the video orbits"))
  assert lines[at - 1].startswith("pose refinement: off")
  assert module.RULE.flips["orbit"] and module.RULE.fields == ("render.orbit_radius",)


def test_the_docs_row_documents_the_module(orbit):
  module, path = orbit
  header = [c.strip() for c in "| rule | statistic | threshold | decides | measured on | prints "
            "(`auto: …`) | override |".strip("|").split("|")]
  page_header = test_auto_doc.rules_table()[0].keys()
  assert list(page_header) == header  # the row's columns are docs/auto.md's
  row = dict(zip(header, [c.strip() for c in _row_block().strip("|").split("|")]))
  assert row["rule"] == module.RULE.row
  quoted = {(m.group(1), m.group(2)): m.group(3)
            for m in test_auto_doc.QUOTED.finditer(row["threshold"])}
  constants = {t.id for node in ast.parse(path.read_text()).body if isinstance(node, ast.Assign)
               for t in node.targets if t.id.isupper() and t.id != "RULE"}
  assert constants and {("orbit", c) for c in constants} == set(quoted)
  for (_, name), value in quoted.items():
    assert ast.literal_eval(value) == getattr(module, name)
  openings = set()
  for function in ast.parse(path.read_text()).body:
    if isinstance(function, ast.FunctionDef) and not function.name.startswith("flip"):
      for node in ast.walk(function):
        if isinstance(node, ast.Return) and isinstance(node.value, ast.Tuple):
          found = [s for e in node.value.elts[1:] for s in test_auto_doc._strings(e)]
          openings.update(o for o in map(test_auto_doc._literal_opening, found) if o)
  assert len(openings) == 2 and all(o in row["prints (`auto: …`)"] for o in openings)
