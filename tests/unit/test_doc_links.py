"""Every relative link in README.md and docs/*.md, and every ``*.md`` page they name, points to an existing file.

Links are Markdown links ``[text](target)`` (web addresses skipped); a ``#fragment`` on a Markdown
page must name one of its headings (GitHub's anchors). Pages named in text (``docs/x.md``,
``deploy/README.md``) are checked too: a renamed or removed page leaves no dangling mention.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PAGES = sorted([REPO / "README.md", *(REPO / "docs").glob("*.md")])
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)")
MENTION = re.compile(r"(?<![\w/.-])((?:docs|deploy|recordings)/[\w./-]+\.md)\b")


def anchors(page: Path) -> set[str]:
    """GitHub's heading anchors of a Markdown page: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.MULTILINE | re.DOTALL)
    heads = re.findall(r"^#{1,6}\s+(.+?)\s*#*$", text, flags=re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in heads}


def targets(page: Path) -> list[tuple[str, str]]:
    """(path relative to the repository, fragment) of every relative link and page mention in ``page``."""
    text = page.read_text()
    out = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:, ...
            continue
        path, _, fragment = target.partition("#")
        resolved = (page.parent / path).resolve() if path else page.resolve()
        out.append((resolved.relative_to(REPO).as_posix() if resolved.is_relative_to(REPO) else str(resolved), fragment))
    out += [(mention, "") for mention in MENTION.findall(text)]
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_relative_link_and_page_mention_resolves(page: Path) -> None:
    broken = []
    for path, fragment in targets(page):
        file = REPO / path
        if not file.exists():
            broken.append(f"{path} (no such file)")
        elif fragment and file.suffix == ".md" and fragment not in anchors(file):
            broken.append(f"{path}#{fragment} (no such heading)")
    assert not broken, f"{page.relative_to(REPO)}: {broken}"


def test_the_link_check_sees_links_fragments_and_mentions() -> None:
    page = REPO / "docs" / "gateway-protocol.md"
    assert ("docs/gateway-protocol.md", "reliability") in targets(page)
    assert "reliability" in anchors(page)
    readme = targets(REPO / "README.md")
    assert any(path == "docs/experiments.md" for path, _ in readme)
