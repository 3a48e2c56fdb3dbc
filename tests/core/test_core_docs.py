"""The README and the docs site (MkDocs, `docs/`): the site builds with no broken link or anchor,
the README's links into it land, what both show is the same text, and every commit they cite
for a measured number is in the repository's history."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

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


# A measured number names the commit it was measured at ("(measured with `...` at commit 1a2b3c4)",
# "at commits 1a2b3c4 and 5d6e7f8"): the hashes after "commit" or "commits", a list joined by
# commas or "and", a line break anywhere between.
CITED = re.compile(r"\bcommits?\s+`?([0-9a-f]{7,40})\b`?((?:(?:\s*,\s*|,?\s+and\s+)`?[0-9a-f]{7,40}\b`?)*)")


def cited_commits(text: str) -> list[str]:
    return [h for first, rest in CITED.findall(text) for h in [first, *re.findall(r"[0-9a-f]{7,40}", rest)]]


def test_the_citation_pattern_reads_every_form_the_pages_use():
    text = ("(measured with `python benchmarks/x.py` at commit 1a2b3c4), at\ncommit 5d6e7f8; at commits 0a1b2c3"
            " and 4d5e6f7, commits 89abcde, fedcba9 and 7654321; at commit abc1234 and then")
    assert cited_commits(text) == ["1a2b3c4", "5d6e7f8", "0a1b2c3", "4d5e6f7", "89abcde", "fedcba9", "7654321",
                                   "abc1234"]
    assert cited_commits("git commit -m 'a message', commit 12ab and commit the change") == []


def test_every_commit_the_pages_cite_is_in_the_history():
    # So that a citation can be neither made up nor mistyped: every "commit <hash>" in the README
    # and the docs' pages names a commit of this repository. A checkout without its history (a
    # source tarball, a shallow clone) cannot tell, and skips.
    git = shutil.which("git")
    top = subprocess.run([git, "rev-parse", "--show-toplevel"], cwd=REPO, capture_output=True, text=True,
                         check=False) if git else None
    if top is None or top.returncode != 0 or Path(top.stdout.strip()).resolve() != REPO:
        pytest.skip("no git history here (a source tarball?)")
    shallow = subprocess.run([git, "rev-parse", "--is-shallow-repository"], cwd=REPO, capture_output=True, text=True,
                             check=False)
    if shallow.stdout.strip() == "true":
        pytest.skip("a shallow clone: older commits are not here")
    cited: dict[str, set[str]] = {}
    for page in [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]:
        for sha in cited_commits(page.read_text()):
            cited.setdefault(sha, set()).add(str(page.relative_to(REPO)))
    assert cited, "the pages cite no commit: the pattern no longer reads their citations"
    unknown = {sha: sorted(pages) for sha, pages in cited.items()
               if subprocess.run([git, "cat-file", "-e", f"{sha}^{{commit}}"], cwd=REPO,
                                 capture_output=True, check=False).returncode != 0}
    assert not unknown, f"commits cited but not in this repository's history: {unknown}"
