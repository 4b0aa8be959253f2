"""The licence and the citation: LICENSE is Apache-2.0's full text, CITATION.cff is CFF 1.2.0
with the fields GitHub and Zenodo read, and pyproject.toml names the same licence."""

import pathlib
import tomllib

import pytest

from tests.helpers import ROOT

ROOT = pathlib.Path(ROOT)


def test_the_licence_is_apache_2_in_full():
  text = (ROOT / "LICENSE").read_text()
  assert text.split()[:5] == ["Apache", "License", "Version", "2.0,", "January"]
  for part in ("TERMS AND CONDITIONS FOR USE, REPRODUCTION, AND DISTRIBUTION", "9. Accepting "
               "Warranty or Additional Liability.", "END OF TERMS AND CONDITIONS"):
    assert part in text
  assert len(text.splitlines()) > 190


def test_the_citation_is_cff_1_2_and_agrees_with_pyproject():
  yaml = pytest.importorskip("yaml")
  cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
  with open(ROOT / "pyproject.toml", "rb") as f:
    project = tomllib.load(f)["project"]
  assert cff["cff-version"] == "1.2.0" and cff["message"] and cff["type"] == "software"
  assert cff["title"] == project["name"] == "nerf_jax"
  assert cff["authors"] == [{"name": "nerf_jax contributors"}]
  assert cff["license"] == project["license"] == "Apache-2.0"
  assert cff["version"] == project["version"]
  assert str(cff["date-released"]) == "2026-11-27"
