"""The documentation: its quick commands run, every page is reachable from the README, and
every relative link points at a file (and a heading) that exists.

A fenced block whose info string is ``bash quick`` holds commands that run in seconds; each
block runs with ``bash -euo pipefail`` in an empty temporary folder, with the repository's
``.venv/bin`` first on ``PATH``, and must exit 0. Blocks without the marker (commands that
need ``DATA``, a GPU or hours) are documentation only.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

from conftest import REPO

README = REPO / "README.md"
DOCS = REPO / "docs"
PAGES = [README, *sorted(DOCS.glob("*.md"))]
#: The pages that must each show commands CI runs: one per package and one per workflow.
PAGES_WITH_QUICK_COMMANDS = [
    "svbrdf-render.md", "svbrdf-models.md", "svbrdf-train.md", "svbrdf-bench.md",
    "capture.md", "train.md", "benchmark.md", "plugins.md",
]
README_LIMIT_BYTES = 15 * 1024

_FENCE = re.compile(r"^```(?P<info>[^\n`]*)\n(?P<body>.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _quick_blocks() -> list[tuple[str, str]]:
    """``(id, commands)`` of every ``bash quick`` block, the id being ``page:line``."""
    out = []
    for page in PAGES:
        text = page.read_text()
        for m in _FENCE.finditer(text):
            if m["info"].split() == ["bash", "quick"]:
                line = text.count("\n", 0, m.start()) + 1
                out.append((f"{page.relative_to(REPO)}:{line}", m["body"]))
    return out


def _without_code(text: str) -> str:
    """The text with fenced blocks and inline code blanked (links there are not links)."""
    text = _FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), text)
    return re.sub(r"`[^`\n]*`", "``", text)


def _links(page: Path) -> list[str]:
    return _LINK.findall(_without_code(page.read_text()))


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    headings = re.findall(r"^#{1,6} +(.+?)[ #]*$", _without_code(page.read_text()), re.MULTILINE)
    return {_slug(h) for h in headings}


QUICK = _quick_blocks()


def test_each_package_and_workflow_page_has_quick_commands():
    pages = {block_id.split(":")[0] for block_id, _ in QUICK}
    missing = [name for name in PAGES_WITH_QUICK_COMMANDS if f"docs/{name}" not in pages]
    assert not missing, f"no `bash quick` block in {missing}"


@pytest.mark.slow
@pytest.mark.parametrize("commands", [c for _, c in QUICK], ids=[i for i, _ in QUICK])
def test_quick_commands_run(commands, tmp_path):
    env = {**os.environ, "PATH": f"{REPO / '.venv' / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"}
    r = subprocess.run(
        ["bash", "-euo", "pipefail", "-c", commands],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )
    assert r.returncode == 0, f"exit {r.returncode}\n{commands}\nstdout:\n{r.stdout[-2000:]}\nstderr:\n{r.stderr[-2000:]}"


def test_readme_is_short():
    size = len(README.read_bytes())
    assert size < README_LIMIT_BYTES, f"README.md is {size} bytes; move detail to docs/ (limit {README_LIMIT_BYTES})"


def test_every_docs_page_is_linked_from_the_readme():
    linked = {(README.parent / link.split("#")[0]).resolve() for link in _links(README) if "://" not in link}
    pages = [p for p in sorted(DOCS.iterdir()) if p.suffix in (".md", ".txt")]
    assert pages, "docs/ holds no page"
    missing = [p.name for p in pages if p.resolve() not in linked]
    assert not missing, f"docs pages the README does not link: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(REPO)) for p in PAGES])
def test_relative_links_resolve(page):
    broken = []
    for link in _links(page):
        if re.match(r"[a-z][a-z0-9+.-]*:", link):  # http:, https:, mailto:
            continue
        path, _, anchor = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        if not target.exists():
            broken.append(f"{link} (no such file)")
        elif anchor and target.suffix == ".md" and anchor not in _anchors(target):
            broken.append(f"{link} (no heading #{anchor} in {target.name})")
    assert not broken, f"{page.relative_to(REPO)}: broken links: {broken}"
