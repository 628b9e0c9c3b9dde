"""Every Markdown table in README.md and docs/*.md has as many cells in each row as in its header:
GitHub shows a table whose delimiter row has another count as raw pipes (the Live table had 16
header cells and 17 delimiter cells), and drops the cells of a row beyond the header's."""

import re

import pytest

from test_blender_helpers import REPO_ROOT

DELIMITER = re.compile(r"^\|?\s*:?-+:?\s*(\|\s*:?-+:?\s*)*\|?\s*$")
FILES = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]


def _cells(line):
    """Cells of a table row as GitHub splits them: at every pipe not escaped by a backslash."""
    s = line.strip()
    s = s[1:] if s.startswith("|") else s
    s = s[:-1] if s.endswith("|") and not s.endswith("\\|") else s
    return len(re.split(r"(?<!\\)\|", s))


def _tables(text):
    """(line number, header cells, [(line number, cells) of the delimiter and body rows])."""
    lines = text.splitlines()
    for i in range(len(lines) - 1):
        if "|" in lines[i] and DELIMITER.match(lines[i + 1]) and "-" in lines[i + 1]:
            rows = []
            for j in range(i + 1, len(lines)):
                if "|" not in lines[j] or not lines[j].strip():
                    break
                rows.append((j + 1, _cells(lines[j])))
            yield i + 1, _cells(lines[i]), rows


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_every_table_row_has_the_header_cell_count(path):
    found = list(_tables(path.read_text()))
    bad = [(ln, head, row, n) for ln, head, rows in found for row, n in rows if n != head]
    assert not bad, [f"{path.name}:{row}: {n} cells, header (line {ln}) {head}" for ln, head, row, n in bad]


def test_tables_are_found():
    assert sum(len(list(_tables(p.read_text()))) for p in FILES) >= 10
