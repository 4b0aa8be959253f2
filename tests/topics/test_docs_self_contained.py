"""README.md and docs/*.md speak of the project alone: no path outside the repository (a
`../shared` folder, a machine's `.gpu/` kit) and no word of the machines a measurement was
borrowed on. A reader of a fresh clone has neither."""

import pathlib
import re

import pytest

from tests.helpers import ROOT

ROOT = pathlib.Path(ROOT)
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# What a page of this repository must not name, and why.
ELSEWHERE = {
    r"\.\./shared|(?<![\w./-])shared/": "a folder outside the repository",
    r"(?<![\w/])\.gpu/": "a kit beside the checkout, not in it",
    r"\b(lent|lend(s|ing)?|borrow(ed|s|ing)?|loan(ed|s)?)\b": "a machine lent to a session",
    r"\bkit\b": "a kit that is not in the repository",
    r"\$OUT\b": "a tool's output folder",
    r"`fetch`": "a tool, not a command of the project",
}


def problems(text):
  """(line number, what, line) of each thing `text` names from outside the repository."""
  return [(number, why, line.strip())
          for number, line in enumerate(text.splitlines(), 1)
          for pattern, why in ELSEWHERE.items() if re.search(pattern, line, re.IGNORECASE)]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_page_names_nothing_outside_the_repository(doc):
  assert problems(doc.read_text()) == []


@pytest.mark.parametrize("line", [
    "see ../shared/gpu/notes.md", "the files in shared/gpu", "bash .gpu/check.sh",
    "No GPU was lent to this session", "the kit's own script", "--out=$OUT/frontier",
    "lego from github:x/y (`fetch`)"])
def test_the_check_catches(line):
  assert problems(line)


@pytest.mark.parametrize("line", [
    "the shared 2-core CPU", "one trained workdir shared by the tests", "a lens, a length",
    "the released files", "docs/gpu.md"])
def test_the_check_passes(line):
  assert problems(line) == []
