"""Every relative link in README.md and docs/*.md reaches a file, and every #anchor a heading there (as
GitHub makes heading anchors): the README's condensed sections send the reader to docs sections by
anchor, and a renamed heading would leave a dead link."""

import re

import pytest

from test_blender_helpers import REPO_ROOT

FILES = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^\s*(```|~~~)")
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _outside_fences(text):
    """(line number, line) of the lines outside fenced code blocks."""
    fenced = False
    for n, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
        elif not fenced:
            yield n, line


def _anchors(path):
    """GitHub's heading anchors: lower case, punctuation but '-' and '_' dropped, spaces to '-',
    repeats numbered -1, -2, ..."""
    seen, out = {}, set()
    for _, line in _outside_fences(path.read_text()):
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_anchors_follow_github():
    path = REPO_ROOT / "docs" / "live.md"
    assert "the-ui-threads-longest-stalls-2026-12-06-branch-ui26" in _anchors(path)


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_every_relative_link_and_anchor_exists(path):
    bad = []
    for n, line in _outside_fences(path.read_text()):
        for target in LINK.findall(line):
            if re.match(r"^[a-z]+:", target):
                continue
            file, _, anchor = target.partition("#")
            dest = (path.parent / file).resolve() if file else path
            if not dest.exists():
                bad.append(f"{path.name}:{n}: no file {target}")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                bad.append(f"{path.name}:{n}: no heading for {target}")
    assert not bad, bad
