"""A plain HTML rendering of the report's Markdown (headings, paragraphs, tables, images)."""

from __future__ import annotations

import html
import re


def markdown_to_html(md: list[str]) -> str:
    """A plain HTML page of Markdown lines: headings, paragraphs, pipe tables, bold and code
    spans, and ``![title](src)`` images inline."""
    body, table = [], []

    def flush():
        if table:
            rows = [r.strip("|").split("|") for r in table if not set(r) <= set("|-")]
            head, *rest = rows
            body.append(
                "<table><tr>"
                + "".join(f"<th>{_inline(c)}</th>" for c in head)
                + "</tr>"
                + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in rest)
                + "</table>"
            )
            table.clear()

    for line in md:
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if line.startswith("!["):
            alt, src = line[2:].split("](")
            body.append(f"<h3>{html.escape(alt)}</h3><img src='{html.escape(src.rstrip(')'))}'>")
        elif line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            body.append(f"<h{level}>{_inline(line.lstrip('#').strip())}</h{level}>")
        elif line.strip():
            body.append(f"<p>{_inline(line)}</p>")
    flush()
    return (
        "<!doctype html><html><head><meta charset='utf-8'><title>VO evaluation</title><style>"
        "body{font-family:system-ui;max-width:1200px;margin:2em auto}img{max-width:100%}"
        "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
        "</style></head><body>" + "\n".join(body) + "</body></html>"
    )


def _inline(text: str) -> str:
    t = html.escape(text.strip())
    t = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", t)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", t)
