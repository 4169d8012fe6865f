"""The documentation holds together and speaks in its own words: every relative link of README.md and
docs/*.md resolves (the file, and the heading a ``#fragment`` names), no page refers to material outside
the repository or to the project's internal history (issue numbers, a spec, commit hashes, dates of
measurements, the papers' seed numbers: docs/reference.md defines and cites instead), and README.md stays
short. Each check first catches faults planted in small texts, so it cannot pass vacuously."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 200

# [text](target) and ![alt](target); the target up to whitespace (an optional "title" may follow)
INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s+<?(\S+?)>?(?:\s+\"[^\"]*\")?\s*$", re.M)
HTML_SRC = re.compile(r"<(?:img|a)\b[^>]*?\b(?:src|href)=\"([^\"]+)\"", re.I)
FENCE = re.compile(r"^ {0,3}(```|~~~)")

# What a page must not say (case-insensitive), with why
FORBIDDEN = {
    "a spec outside the repository": r"\bspec\b",
    "an issue number": r"\bissues?\s*#?\s*\d+",
    "an issue reference": r"\(\s*issue\b",
    "a commit hash": r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7,40}\b",
    "a date": r"\b20\d\d-(?:0[1-9]|1[0-2])(?:-\d\d)?\b",
    "a paper's seed number": r"\bpapers?\s+0\d\d\b|\[00\d\]",
    "a folder outside the repository": r"(?:\.\./)+shared/",
}


def pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def prose(text: str, inline_code: bool = False) -> str:
    """The text with fenced code blocks blanked (kept line for line), and inline code too unless asked to keep
    it: links there are not links."""
    out, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            out.append("")
            continue
        out.append("" if fenced else line if inline_code else re.sub(r"`[^`]*`", "``", line))
    return "\n".join(out)


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, markup and punctuation dropped, spaces as hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading keeps its text
    text = text.replace("`", "").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in prose(path.read_text(encoding="utf-8"), inline_code=True).splitlines():
        m = re.match(r"^ {0,3}#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        base = anchor(m.group(1))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(text: str) -> list[tuple[int, str]]:
    """(line, target) of every link and image of a page's prose."""
    body = prose(text)
    found = []
    for rx in (INLINE_LINK, REFERENCE_DEF, HTML_SRC):
        for m in rx.finditer(body):
            found.append((body.count("\n", 0, m.start()) + 1, m.group(1)))
    return sorted(found)


def broken_links(path: Path, root: Path) -> list[str]:
    """Every relative link of ``path`` whose file, or whose ``#fragment`` in a Markdown file, is missing."""
    bad = []
    for line, target in links(path.read_text(encoding="utf-8")):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("//"):
            continue  # http:, https:, mailto: ...: not a file of the repository
        file_part, _, fragment = target.partition("#")
        dest = path if not file_part else (path.parent / file_part).resolve()
        where = f"{path.relative_to(root)}:{line}: {target}"
        if file_part and not dest.exists():
            bad.append(f"{where}: no such file")
        elif fragment and dest.suffix == ".md" and fragment.lower() not in anchors(dest):
            bad.append(f"{where}: no heading '#{fragment}' in {dest.relative_to(root)}")
        elif file_part and not dest.is_relative_to(root):
            bad.append(f"{where}: outside the repository")
    return bad


def forbidden(text: str) -> list[str]:
    """``line: what: the words`` for every forbidden reference in ``text`` (code blocks included)."""
    bad = []
    for no, line in enumerate(text.splitlines(), 1):
        for what, rx in FORBIDDEN.items():
            for m in re.finditer(rx, line, re.I):
                bad.append(f"{no}: {what}: {m.group(0)!r}")
    return bad


# ------------------------------------------------------------------ the checks catch planted faults


@pytest.mark.parametrize("text", [
    "see issue 12 for why", "as in Issues 26/27", "the round (issue 20)", "spec section 4", "the spec's distances",
    "measured at 9184dc1", "re-run at 2dc2119f and", "measured 2026-12-05 on 2 cores", "the box of 2026-11",
    "paper 000's NM", "Papers 002 and 003", "the list [003] below", "`../shared/spec/README.md`",
])
def test_a_planted_reference_is_caught(text):
    assert forbidden(f"Fine words.\n{text}\n"), text


@pytest.mark.parametrize("text", [
    "specific to the machine", "inspect the rows", "respectively", "an issue of timing", "seed 20 000",
    "1000000 holes", "doi:10.13374/j.issn2095-9389.2024.01.13.002", "Wu et al. 2024, Table 3", "deadbeef",
    "the 2024 paper", "conf/sup_box/working.yaml", "the (issues-free) run",
])
def test_ordinary_words_pass(text):
    assert forbidden(text) == [], text


def test_a_broken_link_is_caught(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# Title\n\n## The round: every boom (`twin`)\n\ntext\n")
    page = tmp_path / "README.md"
    page.write_text(
        "[ok](docs/a.md) [ok](docs/a.md#the-round-every-boom-twin) [ok](#here) ![ok](docs/a.md)\n"
        "[web](https://example.org/x.md) `[not a link](nowhere.md)`\n"
        "```\n[in a code block](nowhere.md)\n```\n"
        "## Here\n"
        "[gone](docs/b.md) ![gone](docs/img/x.png) [no anchor](docs/a.md#nope) [no anchor](#there)\n"
        "[ref]: docs/c.md\n"
    )
    bad = broken_links(page, tmp_path)
    assert sorted(b.split(": ", 1)[1] for b in bad) == sorted([
        "docs/b.md: no such file", "docs/img/x.png: no such file", "docs/a.md#nope: no heading '#nope' in docs/a.md",
        "#there: no heading '#there' in README.md", "docs/c.md: no such file"]), bad


def test_anchor_follows_github():
    assert anchor("The round (`python -m pipeline.schedule schedule.benchmark=true`)") == \
        "the-round-python--m-pipelineschedule-schedulebenchmarktrue"
    assert anchor("7. A rig of several booms, and the round") == "7-a-rig-of-several-booms-and-the-round"
    assert anchor("Boom–boom clearance (`pipeline/geometry/boom_pair.py`)") == \
        "boomboom-clearance-pipelinegeometryboom_pairpy"


# ------------------------------------------------------------------ the project's own pages


def test_the_pages_are_there():
    names = {p.name for p in pages()}
    assert {"README.md", "reference.md", "usage.md", "round.md", "benchmarks.md"} <= names


@pytest.mark.parametrize("page", pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    assert broken_links(page, ROOT) == []


@pytest.mark.parametrize("page", pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_reference_outside_the_repository_or_to_its_history(page):
    bad = forbidden(page.read_text(encoding="utf-8"))
    assert bad == [], f"{page.relative_to(ROOT)}: say it in the docs' own words (docs/reference.md):\n" + "\n".join(bad)


def test_the_readme_stays_short():
    n = len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines, more than {README_MAX_LINES}"
