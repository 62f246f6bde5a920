"""The demo report: one offline HTML page with PNG figures beside it, every number from the run."""

from __future__ import annotations

import html
import re
from dataclasses import dataclass, field
from pathlib import Path

from lmncell.runtime.model import write_text_whole


def _inline(text: str) -> str:
    """Escaped text with `code spans` as <code>."""
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", html.escape(text))


@dataclass
class Report:
    """Sections of figures (with one-line captions), tables and text, written as report.html."""

    title: str
    out: Path
    sections: list[tuple[str, list[str]]] = field(default_factory=list)

    def section(self, heading: str) -> None:
        self.sections.append((heading, []))

    def lead(self, heading: str, body: str) -> None:
        """A section with one paragraph placed before all others (the headline figures)."""
        self.sections.insert(0, (heading, [f"<p>{_inline(body)}</p>"]))

    def text(self, body: str) -> None:
        """A paragraph; `text in backticks` is set as code."""
        self.sections[-1][1].append(f"<p>{_inline(body)}</p>")

    def figure(self, path: Path, caption: str) -> None:
        rel = Path(path).relative_to(self.out)
        self.sections[-1][1].append(
            f'<figure><img src="{html.escape(str(rel))}" '
            f'alt="{html.escape(caption.replace("`", ""))}">'
            f"<figcaption>{_inline(caption)}</figcaption></figure>")

    def table(self, rows: list[dict], columns: list[tuple[str, str, str]],
              caption: str = "") -> None:
        """columns: (key, header, format spec)."""
        head = "".join(f"<th>{html.escape(h)}</th>" for _, h, _ in columns)
        body = ""
        for r in rows:
            cells = []
            for key, _, fmt in columns:
                v = r.get(key, "")
                if v is None:
                    txt = "—"           # a figure that does not exist (e.g. never settled)
                elif isinstance(v, list):
                    txt = ", ".join(format(x, fmt) for x in v) if fmt else str(v)
                elif isinstance(v, float) and fmt:
                    txt = format(v, fmt)
                else:
                    txt = str(v)
                cells.append(f"<td>{html.escape(txt)}</td>")
            body += "<tr>" + "".join(cells) + "</tr>"
        cap = f"<caption>{_inline(caption)}</caption>" if caption else ""
        self.sections[-1][1].append(f"<table>{cap}<tr>{head}</tr>{body}</table>")

    def write(self) -> Path:
        parts = [f"<h2>{html.escape(h)}</h2>" + "".join(items) for h, items in self.sections]
        page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(self.title)}</title>
<style>
body {{ font-family: sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }}
figure {{ margin: 1em 0; }} img {{ max-width: 100%; border: 1px solid #ddd; }}
figcaption {{ font-size: 0.92em; color: #444; }}
table {{ border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }}
td, th {{ border: 1px solid #bbb; padding: 3px 8px; text-align: right; }}
caption {{ text-align: left; font-size: 0.92em; color: #444; padding-bottom: 4px; }}
</style></head><body><h1>{html.escape(self.title)}</h1>
{''.join(parts)}
</body></html>
"""
        path = self.out / "report.html"
        return write_text_whole(path, page)
