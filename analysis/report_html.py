"""``wmr report --html``: the Markdown report as one self-contained HTML page (issue 24).

Rendered from the same ``report.md`` text by the pinned Markdown library (``markdown``, its
``tables``, ``toc``, ``fenced_code`` and ``attr_list`` extensions): figures embedded as base64
``data:`` URIs (the page needs no other file), a table of contents after the title, tables
styled and scrolled sideways on a narrow screen, headings anchored as the Markdown report's
links expect (:func:`analysis.findings.slug`).  The page is several MB; it is written beside
the report (``paper/report.html``) and kept out of git.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from analysis.findings import SUMMARY, slug
from wmr.io import atomic_write_text

__all__ = ["CSS", "SUMMARY_ID", "build", "write", "image_links"]

#: The page's style: readable from a phone (one column, images and tables never wider than the
#: screen, wide tables scroll inside their box) to a desktop (a 60 em column).
CSS = """
body { font: 16px/1.5 system-ui, -apple-system, "Segoe UI", sans-serif; margin: 0 auto;
       max-width: 60em; padding: 0 1em 4em; color: #1b1b1b; }
h1 { font-size: 1.6em; } h2 { font-size: 1.3em; border-bottom: 1px solid #ddd; }
h2, h3 { margin-top: 1.8em; }
img { max-width: 100%; height: auto; }
.table { overflow-x: auto; margin: 1em 0; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: left; vertical-align: top; }
th { background: #f3f3f3; } tr:nth-child(even) td { background: #fafafa; }
code { font-size: 0.92em; background: #f5f5f5; padding: 0 0.2em; }
nav.toc { background: #f7f7f7; padding: 0.5em 1em; margin: 1em 0; }
nav.toc ul { padding-left: 1.2em; margin: 0.2em 0; }
@media (max-width: 40em) { body { font-size: 15px; } th, td { padding: 0.2em 0.3em; } }
"""

#: The anchor of the report's summary ("What the suite found").
SUMMARY_ID = slug(SUMMARY)
_IMG = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")


def image_links(markdown_text: str) -> list[str]:
    """The image targets of a Markdown text, in order (``figures/x.png`` ...)."""
    return [m.group(2) for m in _IMG.finditer(markdown_text)]


def _data_uri(path: Path) -> str:
    kind = {".png": "image/png", ".svg": "image/svg+xml", ".jpg": "image/jpeg",
            ".jpeg": "image/jpeg"}.get(path.suffix.lower())  # fmt: skip
    if kind is None:
        raise ValueError(f"{path}: cannot embed a {path.suffix!r} figure")
    return f"data:{kind};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _place_toc(body: str, toc: str) -> str:
    """The table of contents after the summary (before the section that follows
    ``SUMMARY_ID``), so that the first screen holds the answers; else after the title."""
    at = body.find(f'id="{SUMMARY_ID}"')
    nxt = body.find("<h2", at + 1) if at >= 0 else -1
    if nxt >= 0:
        return body[:nxt] + toc + body[nxt:]
    head, sep, rest = body.partition("</h1>")
    return head + sep + toc + rest if sep else toc + body


def build(markdown_text: str, root: str | Path, title: str = "wmr report") -> str:
    """The self-contained page of a Markdown report whose image links are relative to
    ``root``.

    Raises
    ------
    FileNotFoundError
        An image the report links to is missing under ``root``.
    """
    import markdown

    root = Path(root)
    md = markdown.Markdown(extensions=["tables", "toc", "fenced_code", "attr_list"],
                           extension_configs={"toc": {"slugify": lambda s, sep: slug(s),
                                                      "toc_depth": "2"}})  # fmt: skip
    body = md.convert(markdown_text)
    missing = [t for t in image_links(markdown_text) if not (root / t).exists()]
    if missing:
        raise FileNotFoundError(f"report links missing images under {root}: {missing}")

    def embed(m: re.Match) -> str:
        src = html.unescape(m.group(1))
        return f'src="{_data_uri(root / src)}"' if not src.startswith("data:") else m.group(0)

    body = re.sub(r'src="([^"]+)"', embed, body)
    body = body.replace("<table>", '<div class="table"><table>').replace("</table>",
                                                                         "</table></div>")
    toc = f'<nav class="toc"><strong>Contents</strong>{md.toc}</nav>' if md.toc_tokens else ""
    body = _place_toc(body, toc)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n"
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f"<title>{html.escape(title)}</title>\n<style>{CSS}</style></head>\n"
            f"<body>\n{body}\n</body></html>\n")  # fmt: skip


def write(out: str | Path) -> Path:
    """Write ``out/report.html`` from ``out/report.md`` (its figures under ``out``)."""
    out = Path(out)
    text = (out / "report.md").read_text()
    first = next((ln[2:] for ln in text.splitlines() if ln.startswith("# ")), "wmr report")
    return atomic_write_text(out / "report.html", build(text, out, title=first))
