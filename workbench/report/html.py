"""One self-contained HTML file per report: the Markdown the workbench writes, figures embedded.

:func:`write_html_report` reads a ``report.md`` and writes ``report.html`` beside it: every
figure the Markdown links is embedded as a base64 ``data:`` URI, the style sheet is inline, and
nothing refers outside the file (no http(s), no file links), so the one file can be mailed or
attached to a design review. The converter covers the GitHub-flavoured Markdown the workbench's
reports use (ATX headings, paragraphs, pipe tables with escaped pipes and column alignment,
``-``/``*`` lists, fenced code, inline code, bold, italics, images, links); it is not a general
Markdown implementation (no nested lists, block quotes or reference links). No Markdown package
is installed in the workbench's environment, and this subset keeps it that way.
"""

import base64
import html
import mimetypes
import re
from pathlib import Path
from urllib.parse import unquote

from .output import write_text

__all__ = ["markdown_to_html", "write_html_report", "split_table_row"]

_STYLE = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; max-width: 1100px; margin: 2em auto;
       padding: 0 1em; line-height: 1.45; color: #1f2328; }
h1, h2, h3 { border-bottom: 1px solid #d0d7de; padding-bottom: .2em; }
table { border-collapse: collapse; margin: 1em 0; font-size: 90%; }
th, td { border: 1px solid #d0d7de; padding: 4px 9px; }
th { background: #f6f8fa; }
tr:nth-child(even) td { background: #fafbfc; }
code { background: #f2f4f6; padding: 0 3px; border-radius: 3px; font-size: 90%; }
pre { background: #f6f8fa; padding: .8em; overflow-x: auto; }
img { max-width: 100%; height: auto; display: block; margin: .5em 0; }
.missing { color: #b00; font-style: italic; }
"""

_IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")
_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")


def split_table_row(line):
    """The cells of one GFM table row, as GFM splits them: on every pipe not escaped by a backslash.

    Leading and trailing pipes are optional; ``\\|`` stays a pipe inside its cell (unescaped in
    the returned text). Code spans do not protect pipes (GFM spec, tables extension).
    """
    s = line.strip()
    if s.startswith("|"):
        s = s[1:]
    if s.endswith("|") and not s.endswith("\\|"):
        s = s[:-1]
    cells, cur, i = [], [], 0
    while i < len(s):
        if s[i] == "\\" and i + 1 < len(s) and s[i + 1] == "|":
            cur.append("|")
            i += 2
            continue
        if s[i] == "|":
            cells.append("".join(cur).strip())
            cur = []
        else:
            cur.append(s[i])
        i += 1
    cells.append("".join(cur).strip())
    return cells


def _is_delimiter(line):
    cells = split_table_row(line)
    return "|" in line and all(re.fullmatch(r":?-{1,}:?", c) for c in cells)


def _embed(src, base_dir):
    """A ``data:`` URI of the local file ``src`` (relative to ``base_dir``), or None if there is none."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", src, re.I):      # http:, file:, data: ... never followed
        return None
    p = (Path(base_dir) / unquote(src)) if base_dir is not None else Path(unquote(src))
    if not p.is_file():
        return None
    mime = mimetypes.guess_type(p.name)[0] or "application/octet-stream"
    return f"data:{mime};base64,{base64.b64encode(p.read_bytes()).decode('ascii')}"


def _inline(text, base_dir):
    """Inline Markdown of one block's text -> HTML (code spans first, so their content stays literal)."""
    out = []
    for k, part in enumerate(re.split(r"(`[^`]*`)", text)):
        if k % 2:
            out.append(f"<code>{html.escape(part[1:-1])}</code>")
            continue
        part = part.replace("\\|", "|")
        slots = []

        def keep(markup):
            slots.append(markup)
            return f"\x00{len(slots) - 1}\x00"

        def image(m):
            uri = _embed(m.group(2), base_dir)
            alt = html.escape(m.group(1), quote=True)
            if uri is None:
                return keep(f'<span class="missing">[figure {alt}: {html.escape(m.group(2))} not found]</span>')
            return keep(f'<img alt="{alt}" src="{uri}">')

        def link(m):
            # local links become their text: the HTML must not point outside itself
            return keep(f"<u>{html.escape(m.group(1))}</u>")

        part = _LINK.sub(link, _IMAGE.sub(image, part))
        part = html.escape(part, quote=False)
        part = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", part)
        part = re.sub(r"(?<![\w*])\*(?!\s)(.+?)(?<!\s)\*(?![\w*])", r"<em>\1</em>", part)
        part = re.sub(r"(?<![\w])_(?!\s)(.+?)(?<!\s)_(?![\w])", r"<em>\1</em>", part)
        part = re.sub("\x00(\\d+)\x00", lambda m: slots[int(m.group(1))], part)
        out.append(part)
    return "".join(out)


def _align(cell):
    left, right = cell.startswith(":"), cell.endswith(":")
    return ' style="text-align:center"' if left and right else (' style="text-align:right"' if right else "")


def markdown_to_html(text, base_dir=None, title=None):
    """A complete, self-contained HTML document of the workbench's Markdown ``text``.

    Parameters
    ----------
    text : str
        The report's Markdown.
    base_dir : path-like, optional
        The folder the Markdown's image links are relative to (the report's folder).
    title : str, optional
        The document title (default: the first heading).

    Returns
    -------
    str
    """
    lines = text.splitlines()
    body, para, i = [], [], 0

    def flush():
        if para:
            body.append(f"<p>{_inline(' '.join(para), base_dir)}</p>")
            para.clear()

    while i < len(lines):
        line = lines[i]
        s = line.strip()
        if not s:
            flush()
            i += 1
        elif s.startswith("```"):
            flush()
            j = i + 1
            while j < len(lines) and not lines[j].strip().startswith("```"):
                j += 1
            body.append("<pre><code>" + html.escape("\n".join(lines[i + 1:j])) + "</code></pre>")
            i = j + 1
        elif re.match(r"#{1,6}\s", s):
            flush()
            level = len(s) - len(s.lstrip("#"))
            heading = s[level:].strip()
            title = title or re.sub(r"`|\*\*", "", heading)
            body.append(f"<h{level}>{_inline(heading, base_dir)}</h{level}>")
            i += 1
        elif "|" in s and i + 1 < len(lines) and _is_delimiter(lines[i + 1]):
            flush()
            head, delim = split_table_row(line), split_table_row(lines[i + 1])
            aligns = [_align(c) for c in delim] + [""] * len(head)
            rows = ["<tr>" + "".join(f"<th{aligns[k]}>{_inline(c, base_dir)}</th>" for k, c in enumerate(head))
                    + "</tr>"]
            i += 2
            while i < len(lines) and lines[i].strip() and "|" in lines[i]:
                cells = (split_table_row(lines[i]) + [""] * len(head))[:len(head)]
                rows.append("<tr>" + "".join(f"<td{aligns[k]}>{_inline(c, base_dir)}</td>"
                                             for k, c in enumerate(cells)) + "</tr>")
                i += 1
            body.append("<table>\n<thead>" + rows[0] + "</thead>\n<tbody>\n" + "\n".join(rows[1:])
                        + "\n</tbody>\n</table>")
        elif re.match(r"[-*]\s", s):
            flush()
            items = []
            while i < len(lines) and re.match(r"[-*]\s", lines[i].strip()):
                item = [lines[i].strip()[2:]]
                i += 1
                while i < len(lines) and lines[i].startswith("  ") and lines[i].strip() \
                        and not re.match(r"[-*]\s", lines[i].strip()):
                    item.append(lines[i].strip())
                    i += 1
                items.append(f"<li>{_inline(' '.join(item), base_dir)}</li>")
            body.append("<ul>\n" + "\n".join(items) + "\n</ul>")
        else:
            para.append(s)
            i += 1
    flush()
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"<title>{html.escape(title or 'workbench report')}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
            + "\n".join(body) + "\n</body>\n</html>\n")


def write_html_report(markdown_path, html_path=None):
    """Write the self-contained HTML of the Markdown report ``markdown_path``; returns its path.

    ``html_path`` defaults to the Markdown's name with ``.html`` beside it. Figures are read from
    the links' targets relative to the Markdown file; a missing one is named in the page.
    The file is written whole or not at all.
    """
    md = Path(markdown_path)
    out = Path(html_path) if html_path is not None else md.with_suffix(".html")
    return write_text(out, markdown_to_html(md.read_text(encoding="utf-8"), base_dir=md.parent))
