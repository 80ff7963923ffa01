"""The docs hold: every relative link in README.md, docs/ and benchmarks/ reaches a file of the repository and,
with ``#anchor``, a heading of it (GitHub's anchors); the docs date figures, not development rounds.

No network: links to http(s) and mailto are not followed.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import unquote

import pytest

from checkout import REPO

DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), *sorted((REPO / "benchmarks").glob("*.md"))]

_FENCE = re.compile(r"^(```|~~~).*?^\1", re.M | re.S)
_CODE = re.compile(r"`[^`\n]*`")
_LINK = re.compile(r"(?<!!)\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_IMAGE = re.compile(r"!\[[^\]]*\]\(\s*<?([^)\s>]+)>?")
_REF = re.compile(r"^\s*\[[^\]]+\]:\s*<?(\S+?)>?(?:\s.*)?$", re.M)
_HEADING = re.compile(r"^(#{1,6})\s+(.+?)\s*#*\s*$", re.M)
_HTML_ID = re.compile(r"<a\s+(?:name|id)=\"([^\"]+)\"", re.I)


def prose(text: str) -> str:
    """The text without fenced code blocks and inline code (links there are examples, not links)."""
    return _CODE.sub("", _FENCE.sub("", text))


def links(text: str) -> Iterator[str]:
    """Every link target of a Markdown text: inline links, images, reference definitions."""
    body = prose(text)
    for pattern in (_LINK, _IMAGE, _REF):
        for m in pattern.finditer(body):
            yield m.group(1)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: markup dropped, lower case, punctuation removed, spaces to dashes."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link: its text
    text = re.sub(r"<[^>]+>", "", text).replace("`", "").lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every anchor a Markdown file offers: its headings' slugs (repeats get -1, -2...) and HTML ids."""
    text = path.read_text(encoding="utf-8")
    seen: dict[str, int] = {}
    out = set(_HTML_ID.findall(text))
    for m in _HEADING.finditer(_FENCE.sub("", text)):
        base = slug(m.group(2))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def broken(doc: Path) -> list[str]:
    """The links of ``doc`` that reach no file, or no heading of it."""
    out = []
    for target in links(doc.read_text(encoding="utf-8")):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):
            continue  # http:, https:, mailto: ...: not followed (no network)
        file_part, _, anchor = target.partition("#")
        dest = doc if not file_part else (doc.parent / unquote(file_part)).resolve()
        if not dest.exists() or REPO.resolve() not in (dest, *dest.parents):
            out.append(f"{doc.relative_to(REPO)}: ({target}): no such file in the repository")
        elif anchor and dest.suffix == ".md" and unquote(anchor) not in anchors(dest):
            out.append(f"{doc.relative_to(REPO)}: ({target}): no heading #{anchor} in {dest.relative_to(REPO)}")
    return out


class TestLinkCheck:
    """The checker itself finds what it must."""

    def test_finds_a_broken_file_link_and_anchor(self, tmp_path: Path) -> None:
        """A link from docs/ to ../deploy.md (one level too far up) and to a missing heading are both caught."""
        docs = REPO / "docs"
        text = "[d](../deploy.md) [ok](deploy.md) [a](commands.md#no-such-heading) `[x](nowhere.md)`"
        found = [t for t in links(text)]
        assert found == ["../deploy.md", "deploy.md", "commands.md#no-such-heading"]
        assert not (docs / "../deploy.md").resolve().exists() and (docs / "deploy.md").exists()
        assert "no-such-heading" not in anchors(docs / "commands.md")

    def test_slugs_as_github(self) -> None:
        """Headings become GitHub's anchors: code and punctuation dropped, spaces to dashes."""
        assert slug("`--export-signals`: the samples as a table") == "--export-signals-the-samples-as-a-table"
        assert slug("I²t: the heat model (A²s)") == "i²t-the-heat-model-a²s"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(doc: Path) -> None:
    """Every relative link of README.md, docs/*.md and benchmarks/*.md reaches a file here, and its heading."""
    assert broken(doc) == []


_ROUND = re.compile(r"\b(?:sessions?|issues?|rounds?)[ -]\d+\b|\b(?:the|this) session\b|\bthe issue's\b", re.I)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_figures_dated_not_by_development_round(doc: Path) -> None:
    """Users read the product's docs: figures carry a date and a commit, not "session 9" or "issue 16"."""
    text = doc.read_text(encoding="utf-8")
    found = [f"{doc.relative_to(REPO)}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)}"
             for m in _ROUND.finditer(text)]
    assert found == []
