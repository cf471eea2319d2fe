"""The README and docs/*.md link only to files that exist and to headings that exist (GitHub's
anchor rules: lowercase; every character that is not a letter, digit, space, hyphen or underscore
dropped; spaces to hyphens; a repeated heading gets -1, -2, ...)."""
from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")


def _prose_lines(text: str) -> list[str]:
    """The lines outside fenced code blocks (a fenced line reads as empty)."""
    out, fence = [], False
    for line in text.split("\n"):
        if line.lstrip().startswith("```"):
            fence = not fence
            out.append("")
        else:
            out.append("" if fence else line)
    return out


def slug(heading: str) -> str:
    h = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", h).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen, out = Counter(), set()
    for line in _prose_lines(path.read_text(encoding="utf-8")):
        m = HEADING.match(line)
        if m:
            s = slug(m.group(2))
            out.add(s if seen[s] == 0 else f"{s}-{seen[s]}")
            seen[s] += 1
    return out


def broken_links(root: Path) -> list[str]:
    bad = []
    for f in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        for i, line in enumerate(_prose_lines(f.read_text(encoding="utf-8")), 1):
            for target in LINK.findall(re.sub(r"`[^`]*`", "", line)):     # not in inline code
                if re.match(r"^[a-z][a-z0-9+.-]*:", target):
                    continue                            # http(s), mailto: not checked here
                path, _, anchor = target.partition("#")
                dest = (f.parent / path).resolve() if path else f.resolve()
                if not dest.exists():
                    bad.append(f"{f.relative_to(root)}:{i}: no file {target}")
                elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                    bad.append(f"{f.relative_to(root)}:{i}: no heading #{anchor} in {dest.name}")
    return bad


def test_slug_follows_github():
    assert slug("The seed's published items (`imurig reproduce`)") == "the-seeds-published-items-imurig-reproduce"
    assert slug("Mismatch discovery (issue 5)") == "mismatch-discovery-issue-5"
    assert slug("Monte-Carlo studies") == "monte-carlo-studies"


def test_readme_and_docs_links_resolve(tmp_path):
    assert broken_links(ROOT) == []
    (tmp_path / "docs").mkdir()
    (tmp_path / "README.md").write_text("# A\n\n## B c\n\n[x](#b-c) [y](#b) [z](docs/none.md)\n")
    assert broken_links(tmp_path) == ["README.md:5: no heading #b in README.md", "README.md:5: no file docs/none.md"]
