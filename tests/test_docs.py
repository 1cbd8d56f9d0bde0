"""README stays short, its links and the docs pages' links all resolve, every page is reachable
from README, and no page reads like a development log."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PAGES = [README, *sorted(DOCS.glob("*.md"))]
MAX_README_LINES = 260
"""README is a page for people; the rest lives in docs/."""
MAX_PICTURE_BYTES = 200 * 1024
"""README's picture is committed to the repository: kept small."""
BANNED = (
    r"\bround\b",
    r"\bissues?\b",
    r"before/after",
    r"was tried first",
    r"\bhelpers?\b",
    r"\bthis session\b",
    r"\bprevious release\b",
    r"\bheld[- ]out\b",
    r"how it got here",
)
"""Development-log wording: pages say what is, not how the work went."""
LINK = re.compile(r"!?\[(?:[^\]]|\][^(])*?\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def _prose(text: str) -> str:
    """The text without fenced code blocks and inline code, where brackets are not links."""
    text = re.sub(r"^```.*?^```[^\n]*$", "", text, flags=re.DOTALL | re.MULTILINE)
    return re.sub(r"`[^`\n]*`", "", text)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = heading.strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every heading anchor of a page, repeated headings numbered as GitHub numbers them."""
    seen: Counter[str] = Counter()
    found = set()
    prose = re.sub(r"^```.*?^```[^\n]*$", "", page.read_text(), flags=re.DOTALL | re.MULTILINE)
    for match in re.finditer(r"^#{1,6} +(.+?) *#*$", prose, flags=re.MULTILINE):
        base = slug(match.group(1))
        found.add(base if seen[base] == 0 else f"{base}-{seen[base]}")
        seen[base] += 1
    return found


def links(page: Path) -> list[str]:
    """The targets of every Markdown link and image of a page, outside code."""
    return LINK.findall(_prose(page.read_text()))


def broken(page: Path, target: str) -> str | None:
    """Why a relative link does not resolve, or None when it does (or is not relative)."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target):
        return None  # https:, mailto: and the like
    name = page.relative_to(ROOT) if page.is_relative_to(ROOT) else page
    path_part, _, anchor = target.partition("#")
    destination = (page.parent / path_part).resolve() if path_part else page
    if not destination.exists():
        return f"{name}: {target} (no such file)"
    if anchor and destination.suffix == ".md" and anchor not in anchors(destination):
        return f"{name}: {target} (no such heading)"
    return None


def test_slug_follows_githubs_rules() -> None:
    """Headings with punctuation, code and apostrophes give GitHub's anchors."""
    assert slug("Can you trust the map? The verdict") == "can-you-trust-the-map-the-verdict"
    assert slug("Real robots' logs") == "real-robots-logs"
    assert slug("Scoring a map against a reference: `compare`") == (
        "scoring-a-map-against-a-reference-compare"
    )
    assert slug("Many logs: a saved map") == "many-logs-a-saved-map"


def test_readme_is_short() -> None:
    """README is at most 260 lines."""
    lines = len(README.read_text().splitlines())
    assert lines <= MAX_README_LINES, f"README.md has {lines} lines"


def test_every_relative_link_resolves() -> None:
    """Every relative link in README and docs/*.md names a file that exists, and its #anchor a
    heading of that page."""
    assert sum(len(links(page)) for page in PAGES) >= len(PAGES)
    offenders = [
        reason for page in PAGES for target in links(page) if (reason := broken(page, target))
    ]
    assert not offenders, "\n".join(offenders)


def test_a_broken_link_is_found(tmp_path: Path) -> None:
    """The link check fails on a missing file and on a missing heading."""
    page = tmp_path / "page.md"
    page.write_text("# Title\n\n## A part\n\n[ok](#a-part) [bad](#nowhere) [gone](other.md)\n")
    reasons = [broken(page, target) for target in LINK.findall(_prose(page.read_text()))]
    assert reasons[0] is None and reasons[1] is not None and reasons[2] is not None


@pytest.mark.parametrize("pattern", BANNED)
def test_no_page_reads_like_a_development_log(pattern: str) -> None:
    """No page speaks of how the work was organised or measured over time."""
    offenders = [
        f"{page.relative_to(ROOT)}:{number}: {line.strip()}"
        for page in PAGES
        for number, line in enumerate(page.read_text().splitlines(), start=1)
        if re.search(pattern, line, flags=re.IGNORECASE)
    ]
    assert not offenders, "\n".join(offenders)


def test_every_docs_page_is_linked_from_readme() -> None:
    """README links every docs/*.md page, so none is orphaned."""
    targets = {(ROOT / t.partition("#")[0]).resolve() for t in links(README)}
    missing = [p.name for p in sorted(DOCS.glob("*.md")) if p.resolve() not in targets]
    assert not missing, missing


def test_readme_picture_is_small() -> None:
    """Every image README shows is in the repository and under 200 KB."""
    images = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", README.read_text())
    assert images
    for image in images:
        size = (ROOT / image).stat().st_size
        assert size < MAX_PICTURE_BYTES, f"{image}: {size} bytes"
