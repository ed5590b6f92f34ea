"""The product speaks of itself only: no development history in README, docs or the library.

Development history (sessions, issue numbers, review ids, commit hashes, branch names) belongs in
``CHANGELOG.md``.  This test greps the README, ``docs/`` and the library packages (with the scripts and
benchmarks shipped beside them) for those patterns; a sibling test shows that each pattern rejects a
planted example and passes its product-speaking rewrite.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: What is scanned: the user's guide, the documentation, the library packages, scripts and benchmarks.
SCANNED = ["README.md", "docs", "mbs_models", "linearize", "stability", "taguchi", "validation", "flexstab",
           "scripts", "benchmarks"]
SUFFIXES = {".py", ".md", ".html", ".txt", ".toml", ".css", ".j2"}

#: Names of development branches (history, not product).
_BRANCHES = ("dominant64", "phat64", "fixhill", "frame64", "expm64", "fixjac", "fixtune", "prop64", "orbit64",
             "fixes2", "twolink", "house20", "acc19", "rot18", "campbell18", "verdict21", "measure21", "cli22",
             "report22")

PATTERNS = {
    "session": re.compile(r"\bsessions?\b", re.I),
    "issue": re.compile(r"\bissue(?:s|'s)?\b", re.I),
    "review": re.compile(r"\breview\w*", re.I),
    # review ids such as S6, S2.1, H3 (L9, L18 are orthogonal arrays and M0, m1 variables: not matched)
    "review id": re.compile(r"\b[SH]\d{1,2}(?:\.\d+)?\b"),
    # a commit hash: 7-40 hex digits with at least one letter and one digit, not part of a number
    "commit hash": re.compile(r"(?<![\w.#])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w.+-])"),
    "branch": re.compile(r"\b(?:%s|issue\d+)\b" % "|".join(_BRANCHES)),
}

#: The performance page states the commit its table was measured at (that is what a measurement needs).
_MEASURED_AT = re.compile(r"at commit `[0-9a-f]{7,40}`")


def history_hits(text: str, *, allow_measured_commit: bool = False) -> list[tuple[int, str, str]]:
    """``(line number, pattern name, line)`` of every line of ``text`` that carries development history."""
    hits = []
    for number, line in enumerate(text.splitlines(), 1):
        probe = _MEASURED_AT.sub("at commit `<hash>`", line) if allow_measured_commit else line
        for name, pattern in PATTERNS.items():
            if pattern.search(probe):
                hits.append((number, name, line.strip()))
    return hits


def _files():
    for entry in SCANNED:
        path = ROOT / entry
        if path.is_file():
            yield path
        elif path.is_dir():
            for f in sorted(path.rglob("*")):
                if f.is_file() and f.suffix in SUFFIXES and "__pycache__" not in f.parts \
                        and not any(p.endswith(".egg-info") for p in f.parts):
                    yield f


def test_no_development_history_in_the_product():
    found = []
    for f in _files():
        rel = f.relative_to(ROOT).as_posix()
        for number, name, line in history_hits(f.read_text(errors="replace"),
                                               allow_measured_commit=rel == "docs/performance.md"):
            found.append(f"{rel}:{number}: [{name}] {line[:120]}")
    assert not found, "development history in the product (move it to CHANGELOG.md):\n" + "\n".join(found)


def test_the_scan_covers_the_product():
    """The scan reads the README, the docs and every package (an empty scan would pass anything)."""
    files = {f.relative_to(ROOT).as_posix() for f in _files()}
    assert "README.md" in files and "stability/floquet.py" in files and "flexstab/cli.py" in files
    assert any(f.startswith("docs/") for f in files)
    assert "CHANGELOG.md" not in files


@pytest.mark.parametrize("planted, rewrite", [
    ('"title": "Two-link flexible arm (issue 11)"', '"title": "Two-link flexible arm"'),
    ("Measured on the idle machine (session 4, after the last merge)", "Measured on the idle machine"),
    ("(the adaptive path, review4 H2)", "(the adaptive path)"),
    ('"""S2.1: ``measure`` at the kd2 = 0 runs"""', '"""``measure`` at the kd2 = 0 runs"""'),
    ('"before" is commit f539110 (damped Newton only)', '"before" is the damped-Newton-only solver'),
    ("Merge branch 'frame64' into expm64", "the frozen-modal frame and the block exponential"),
])
def test_the_patterns_reject_a_planted_example(planted, rewrite):
    assert history_hits(planted), planted
    assert not history_hits(rewrite), rewrite


def test_numbers_and_orthogonal_arrays_are_not_history():
    text = ("THETA = 1.495585217958292e-2; 0.30013175 and 43.85161638; L9, L18, L27; M0 = K[0]; "
            "a RuntimeWarning is issued; colour #1f77b4; H vs H/2 harmonics")
    assert history_hits(text) == []


def test_only_the_performance_page_may_name_its_commit():
    line = "Measured 2026-12-02 at commit `9012faf`, on a shared 2-core machine"
    assert history_hits(line)
    assert not history_hits(line, allow_measured_commit=True)
    assert history_hits(line + " (after review S3)", allow_measured_commit=True)
