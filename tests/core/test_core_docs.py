"""The README and the docs site (MkDocs, `docs/`): the site builds with no broken link or anchor,
the README's links into it land, and what both show is the same text."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
README = (REPO / "README.md").read_text()


def fenced_block_after(text: str, heading: str) -> str:
    """The first fenced code block after `heading`."""
    rest = text[text.index(heading):]
    start = rest.index("```")
    body = rest[rest.index("\n", start) + 1:]
    return body[: body.index("```")]


def build_site(site: Path) -> subprocess.CompletedProcess:
    # --strict turns mkdocs.yml's `validation` warnings (missing page, missing anchor, a page
    # left out of the nav) into a failed build.
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(REPO / "mkdocs.yml"),
                           "-d", str(site)], capture_output=True, text=True)


def test_the_docs_site_builds_with_no_broken_link(tmp_path):
    proc = build_site(tmp_path / "site")
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (tmp_path / "site" / "index.html").exists()


def test_a_broken_anchor_fails_the_build(tmp_path):
    # The check above means something only if mkdocs really rejects a link to a missing anchor.
    docs = tmp_path / "docs"
    docs.mkdir()
    for page in (REPO / "docs").glob("*.md"):
        (docs / page.name).write_text(page.read_text())
    (docs / "tests.md").write_text((docs / "tests.md").read_text() + "\n[x](judges.md#no-such-heading)\n")
    (tmp_path / "mkdocs.yml").write_text((REPO / "mkdocs.yml").read_text())
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
                          cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode != 0 and "no-such-heading" in proc.stderr


def test_the_readmes_links_into_the_docs_land(tmp_path):
    assert build_site(tmp_path / "site").returncode == 0
    links = re.findall(r"\]\(docs/([\w-]+)\.md(?:#([\w-]+))?\)", README)
    assert {page for page, _ in links} == {p.stem for p in (REPO / "docs").glob("*.md")} - {"index"}
    for page, anchor in links:
        html = (tmp_path / "site" / page / "index.html").read_text()
        assert not anchor or f'id="{anchor}"' in html, f"README links to docs/{page}.md#{anchor}, which has no such heading"


def test_the_readme_is_short():
    assert len(README.splitlines()) <= 250


def test_the_docs_show_the_readmes_commands_and_picture_as_the_readme_does():
    # The two copies a reader meets first (the README on GitHub, the site's own pages) stay one text.
    install = (REPO / "docs" / "install.md").read_text()
    assert fenced_block_after(install, "# Install") == fenced_block_after(README, "## Quick start")
    pipeline = (REPO / "docs" / "pipeline.md").read_text()
    assert fenced_block_after(pipeline, "# The pipeline") == fenced_block_after(README, "## The pipeline")


def test_the_tests_page_names_every_benchmark():
    # docs/tests.md is where a reader learns which benchmarks exist: a new script goes in its list.
    page = (REPO / "docs" / "tests.md").read_text()
    scripts = sorted(p.name for p in (REPO / "benchmarks").glob("*.py"))
    assert scripts and [s for s in scripts if f"`python benchmarks/{s}" not in page] == []
