"""The report's prose rule: what counts as a sentence, and how long one may be (issue 24).

The rule, written once and used by the tests and by :func:`long_sentences`:

- **Prose** is every line of a Markdown text except table rows (a line starting with ``|``),
  headings (``#``), image lines (``![``), fenced code (between ````` lines) and HTML lines
  (``<``).  A list item is prose once its marker (``-``, ``*``, ``1.``) is taken off.
  Consecutive prose lines form one paragraph; a blank line or a non-prose line ends it.
- A **sentence** ends at ``.``, ``!`` or ``?`` (optionally followed by ``)``, ``*``, ``_`` or a
  quote) that is followed by white space and then an upper-case letter, a digit, ``*``, ``(``,
  `````, or the end of the paragraph; except when the word before the full stop is an
  abbreviation (:data:`ABBREVIATIONS`: "eq.", "e.g.", "et al." ...) or a single letter or digit
  (an initial or a list number).
- A sentence's **length** is its number of white-space separated words; code spans count as
  the words they contain.

Every study's generated prose keeps sentences to :data:`MAX_WORDS` words, and the report's
summary ("What the suite found") to :data:`SUMMARY_MAX_WORDS` words in all.
"""

from __future__ import annotations

import re

__all__ = ["ABBREVIATIONS", "MAX_WORDS", "SUMMARY_MAX_WORDS", "paragraphs", "sentences", "words",
           "long_sentences"]  # fmt: skip

#: The longest generated sentence allowed [words].
MAX_WORDS = 60
#: The longest summary allowed [words].
SUMMARY_MAX_WORDS = 600
#: Words whose full stop does not end a sentence (compared in lower case, without the stop).
ABBREVIATIONS = frozenset({
    "eq", "eqs", "e.g", "i.e", "cf", "al", "vs", "fig", "figs", "approx", "ca", "resp", "no",
    "sec", "ref", "refs", "ch", "etc", "incl", "std", "max", "min", "med", "n.b", "p", "pp",
    "viz", "w.r.t", "dr", "prof", "st",
})  # fmt: skip

_FENCE = re.compile(r"^\s*```")
_MARKER = re.compile(r"^\s*(?:[-*+]|\d+[.)])\s+")
_END = re.compile(r"[.!?][)*_\"'”’]*(?=\s+(?:[A-Z0-9*(`]|$)|\s*$)")


def paragraphs(text: str) -> list[str]:
    """The prose paragraphs of a Markdown text (the module's rule), list markers removed."""
    out: list[str] = []
    cur: list[str] = []
    fenced = False

    def flush():
        if cur:
            out.append(" ".join(cur))
            cur.clear()

    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            flush()
            continue
        s = line.strip()
        if fenced or not s or s[0] in "|#<" or s.startswith("!["):
            flush()
            continue
        m = _MARKER.match(line)
        if m:  # a list item starts a paragraph of its own
            flush()
            s = line[m.end():].strip()
        cur.append(s)
    flush()
    return out


def _ends_sentence(paragraph: str, stop: int) -> bool:
    """Whether the punctuation at ``stop`` ends a sentence (not an abbreviation or initial)."""
    if paragraph[stop] != ".":
        return True
    word = paragraph[:stop].split()[-1] if paragraph[:stop].split() else ""
    word = word.lstrip("(*_\"'“‘").lower()
    return not (word in ABBREVIATIONS or (len(word) <= 1 and word.isalpha()))  # "%." ends one


def sentences(text: str) -> list[str]:
    """The sentences of a Markdown text's prose (the module's rule), in order."""
    out = []
    for par in paragraphs(text):
        start = 0
        for m in _END.finditer(par):
            if _ends_sentence(par, m.start()):
                s = par[start:m.end()].strip()
                if s:
                    out.append(s)
                start = m.end()
        rest = par[start:].strip()
        if rest:
            out.append(rest)
    return out


def words(sentence: str) -> int:
    """The number of words of a sentence (white-space separated tokens)."""
    return len(sentence.split())


def long_sentences(text: str, limit: int = MAX_WORDS) -> list[tuple[int, str]]:
    """``(words, sentence)`` for every sentence of the text longer than ``limit`` words."""
    return [(words(s), s) for s in sentences(text) if words(s) > limit]
