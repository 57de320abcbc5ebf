"""The report's opening and its prose (issue 24): the sentence rule on written examples, the
summary's numbers read from the records (perturbed copies change them), every sentence of the
committed report within the limit, and the self-contained HTML page (built, every figure and
table in it, rendered by a headless Chromium)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from analysis import findings, prose, report, report_html
from wmr import cli

PAPER = Path(__file__).resolve().parents[1] / "paper"
needs_paper = pytest.mark.skipif(not (PAPER / "results" / "reproduction.json").exists(),
                                 reason="paper/ not generated yet (make reproduce)")  # fmt: skip


# --- the sentence rule ---------------------------------------------------------------------


@pytest.mark.parametrize("text, expected", [
    ("One. Two three.", ["One.", "Two three."]),
    ("See eq. 22 and e.g. the Jacobian. Next one.", ["See eq. 22 and e.g. the Jacobian.",
                                                     "Next one."]),
    ("Silaa et al. 2024 wrote it. A 0.5 m step.", ["Silaa et al. 2024 wrote it.", "A 0.5 m step."]),
    ("Initials J. R. Doe. At 95 %. Then", ["Initials J. R. Doe.", "At 95 %.", "Then"]),
    ("Is it? **Yes.** (It is.)", ["Is it?", "**Yes.**", "(It is.)"]),
    ("ends in lower case. not a new sentence", ["ends in lower case. not a new sentence"]),
    ("| a | b. C |\n|---|---|\n# Head. Line\n![x. Y](f.png)\n- item one. Item two",
     ["item one.", "Item two"]),
    ("first line\ncontinues. Second\n\nnew paragraph", ["first line continues.", "Second",
                                                        "new paragraph"]),
    ("```\ncode. Not prose\n```\nprose", ["prose"]),
])  # fmt: skip
def test_the_sentence_rule(text, expected):
    assert prose.sentences(text) == expected


def test_long_sentences_counts_words():
    long = " ".join(["Word"] + ["word"] * 60) + "."
    assert prose.long_sentences(f"Short. {long} Short again.") == [(61, long)]
    assert prose.long_sentences(" ".join(["word"] * 60) + ".") == []


def test_slug_is_the_anchor_github_makes():
    assert findings.slug("Tables 1–3: the paper beside this reproduction") == \
        "tables-13-the-paper-beside-this-reproduction"
    assert findings.slug("Linearised loops: margins (python-control)") == \
        "linearised-loops-margins-python-control"


# --- the summary -------------------------------------------------------------------------


def _summary(out) -> str:
    return "\n".join(findings.render(findings.findings(out)))


@needs_paper
def test_the_summary_opens_the_report_and_links_its_sections():
    text = (PAPER / "report.md").read_text()
    heads = re.findall(r"^## (.+)$", text, flags=re.M)
    assert heads[0] == findings.SUMMARY
    summary = _summary(PAPER)
    anchors = re.findall(r"\]\(#([^)]+)\)", summary)
    assert len(anchors) == len(findings.findings(PAPER)) >= 3
    assert set(anchors) <= {findings.slug(h) for h in heads}


@needs_paper
def test_the_summary_is_short_and_its_paragraphs_have_at_most_three_sentences():
    summary = _summary(PAPER)
    n = sum(prose.words(p) for p in prose.paragraphs(summary))
    assert 0 < n <= prose.SUMMARY_MAX_WORDS
    for f in findings.findings(PAPER):
        assert len(prose.sentences(f.text)) <= 3, f.question
        assert prose.long_sentences(f.text) == [], f.question


#: Decimals of the summary not read from a record's floats: the 0.1 of a record key's name
#: (``printed_fraction_above_0.1``) and the calibration power's distance 0.3 (a key of its
#: ``planted.power``, the rule's design constant).
_CITED = {"0.1", "0.3"}


#: The k-th float of a record is scaled by 2 + frac(k phi) (phi the golden ratio): unequal and
#: not periodic, so that a ratio of two numbers moves too, and at least 2x, so that a number
#: printed to one significant digit moves as well.
PHI = (1 + 5**0.5) / 2


def _perturb(obj, count):
    if isinstance(obj, bool) or isinstance(obj, int):
        return obj
    if isinstance(obj, float):
        count[0] += 1
        return obj * (2.0 + (count[0] * PHI) % 1.0)
    if isinstance(obj, list):
        return [_perturb(x, count) for x in obj]
    if isinstance(obj, dict):
        return {k: _perturb(v, count) for k, v in obj.items()}
    return obj


def _numbers(text: str) -> list[str]:
    text = re.sub(r"\]\(#[^)]*\)", "]", text)  # anchors are not numbers
    text = re.sub(r"\[→[^\]]*\]", "", text)  # nor are section titles
    text = re.sub(r"!\[[^\]]*\]\([^)]*\)", "", text)  # nor figure names
    return re.findall(r"\d+(?:\.\d+)?(?:e[-+]\d+)?", text)


@needs_paper
def test_every_decimal_of_the_summary_moves_with_the_records(tmp_path):
    """Scale the floats of a copy of the records by unequal factors: each decimal number of the
    summary changes (a number typed by hand would not); what stays is an integer of the records
    (a count) or one of the cited constants."""
    copy = tmp_path / "paper"
    shutil.copytree(PAPER / "results", copy / "results")
    before = _numbers(_summary(copy))
    for path in (copy / "results").glob("*.json"):
        path.write_text(json.dumps(_perturb(json.loads(path.read_text()), [0])))
    after = _numbers(_summary(copy))
    assert len(before) == len(after) >= 20
    kept = [b for b, a in zip(before, after, strict=True)
            if a == b and "." in b and b not in _CITED]  # fmt: skip
    assert kept == [], f"numbers that did not move with the records: {kept}"


# --- the prose of the whole report ----------------------------------------------------------


#: Sections whose generated prose is being rewritten this round (issues 21-23 change their
#: renders); emptied as they land.
PENDING: tuple[str, ...] = ()  # sections still over the limit: none


@needs_paper
def test_no_generated_sentence_of_the_report_is_longer_than_the_limit():
    text = (PAPER / "report.md").read_text()
    long = [(head.splitlines()[0], n, s) for head in re.split(r"^## ", text, flags=re.M)
            if not head.startswith(PENDING) for n, s in prose.long_sentences(head)]  # fmt: skip
    assert long == [], "\n".join(f"{h}: {n} words: {s[:120]}..." for h, n, s in long)


# --- the HTML page -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    if not (PAPER / "results" / "reproduction.json").exists():
        pytest.skip("paper/ not generated yet (make reproduce)")
    out = tmp_path_factory.mktemp("html") / "paper"
    for sub in ("results", "figures"):
        shutil.copytree(PAPER / sub, out / sub)
    assert cli.main(["report", "--out", str(out), "--html"]) == 0
    return out


def test_the_page_holds_every_figure_and_table_and_nothing_outside(page):
    md = (page / "report.md").read_text()
    assert md == (PAPER / "report.md").read_text()  # the page is made from the same report
    text = (page / "report.html").read_text()
    images = report_html.image_links(md)
    assert len(images) >= 6
    embedded = re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,', text)
    assert embedded == re.findall(r"!\[([^\]]*)\]\([^)]+\)", md)
    assert "src=\"figures/" not in text and "href=\"figures/" not in text
    lines = md.splitlines()
    n_tables = sum(1 for i, ln in enumerate(lines)
                   if ln.startswith("|") and (i == 0 or not lines[i - 1].startswith("|")))
    assert text.count("<table>") == n_tables > 10
    for head in re.findall(r"^## (.+)$", md, flags=re.M):
        assert f'id="{findings.slug(head)}"' in text, head
    # the contents come after the summary, so the first screen holds the answers
    assert text.index(f'id="{report_html.SUMMARY_ID}"') < text.index('<nav class="toc">')


def test_a_missing_figure_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="gone.png"):
        report_html.build("# T\n\n![x](figures/gone.png)\n", tmp_path)


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def test_a_headless_browser_renders_the_page(page, tmp_path):
    exe = _chromium()
    if exe is None:
        if os.environ.get("CI") == "true":
            pytest.fail("CI=true and no chromium: .ci/run installs it (apt-get install chromium)")
        pytest.skip("no chromium on this machine (CI installs it: .ci/run)")
    flags = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
             "--no-first-run", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}"]  # fmt: skip
    url = (page / "report.html").as_uri()
    dom = subprocess.run([*flags, "--dump-dom", url], capture_output=True, text=True, timeout=180)
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert f'id="{report_html.SUMMARY_ID}"' in dom.stdout
    n_images = len(report_html.image_links((page / "report.md").read_text()))
    assert dom.stdout.count("<img") == n_images
    shot = tmp_path / "narrow.png"
    res = subprocess.run([*flags, "--window-size=400,2400", f"--screenshot={shot}", url],
                         capture_output=True, text=True, timeout=180)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000


def test_report_build_is_deterministic():
    if not (PAPER / "results" / "reproduction.json").exists():
        pytest.skip("paper/ not generated yet")
    assert report.build(PAPER) == report.build(PAPER)
