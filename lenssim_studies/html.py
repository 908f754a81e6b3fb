"""Self-contained HTML pages of results: figures embedded as data URIs, tables, one file that opens from disk.

A small script in each page records, once the page has loaded, how many images decoded
(``<div id="load-check" data-loaded=.. data-total=..>``), so a headless browser can check the page.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

from lenssim.io.files import atomic_write_text

__all__ = ["image", "row", "table", "markdown", "page", "write_page"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.3em 0.6em; text-align: left; vertical-align: top; }
th { background: #f0f0f0; } figure { margin: 1em 0; } img { max-width: 100%; }
figcaption { font-size: 0.85em; color: #555; } .muted { color: #666; font-size: 0.85em; }
.row { display: flex; gap: 1em; flex-wrap: wrap; } .row figure { flex: 1 1 22%; margin: 0.5em 0; }
.row img { width: 100%; image-rendering: pixelated; }
"""

_CHECK = """
<div id="load-check" data-loaded="-1" data-total="-1"></div>
<script>
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  var el = document.getElementById("load-check");
  el.setAttribute("data-loaded", ok); el.setAttribute("data-total", imgs.length);
  el.setAttribute("data-tables", document.getElementsByTagName("table").length);
});
</script>
"""

_MIME = {".png": "image/png", ".svg": "image/svg+xml", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}


def image(path, caption: str = "", alt: str = "") -> str:
    """A ``<figure>`` with the image file embedded (base64 data URI) and its caption."""
    p = Path(path)
    data = base64.b64encode(p.read_bytes()).decode("ascii")
    src = f"data:{_MIME.get(p.suffix.lower(), 'application/octet-stream')};base64,{data}"
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img src="{src}" alt="{html.escape(alt or caption or p.name)}">{cap}</figure>'


def row(figures: list[str]) -> str:
    """Figures side by side (each scaled to the row, pixels kept sharp)."""
    return '<div class="row">' + "".join(figures) + "</div>"


def table(header: list[str], rows: list[list], caption: str = "") -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def markdown(text: str) -> str:
    """The Markdown this project writes (headings, paragraphs, pipe tables, inline code) as HTML."""
    out, para, tbl = [], [], []

    def inline(s: str) -> str:
        parts = html.escape(s).split("`")
        return "".join(f"<code>{p}</code>" if i % 2 else p for i, p in enumerate(parts))

    def flush():
        if para:
            out.append(f"<p>{inline(' '.join(para))}</p>")
            para.clear()
        if tbl:
            cells = [[c.strip() for c in ln.strip().strip("|").split("|")] for ln in tbl
                     if not set(ln.replace("|", "").strip()) <= set("-: ")]
            head, *rows = cells
            out.append("<table><thead><tr>" + "".join(f"<th>{inline(c)}</th>" for c in head) + "</tr></thead><tbody>"
                       + "".join("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in r) + "</tr>" for r in rows)
                       + "</tbody></table>")
            tbl.clear()

    for line in text.splitlines():
        if line.startswith("|"):
            if para:
                flush()
            tbl.append(line)
            continue
        if tbl:
            flush()
        if line.startswith("#"):
            flush()
            level = min(len(line) - len(line.lstrip("#")) + 1, 4)
            out.append(f"<h{level}>{inline(line.lstrip('#').strip())}</h{level}>")
        elif not line.strip():
            flush()
        else:
            para.append(line.strip())
    flush()
    return "\n".join(out)


def page(title: str, body: list[str], note: str = "") -> str:
    foot = f'<p class="muted">{html.escape(note)}</p>' if note else ""
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>\n" + "\n".join(body)
            + f"\n{foot}{_CHECK}</body></html>\n")


def write_page(path, title: str, body: list[str], note: str = "") -> Path:
    return atomic_write_text(path, page(title, body, note))
