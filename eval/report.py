"""Report documents: one structure, written as Markdown and as self-contained HTML.

A :class:`Report` is a title and a list of sections; a section holds
paragraphs, tables and figures (PNG files). ``report.md`` links the PNGs
beside it; ``report.html`` embeds them as base64 so the single file can be
mailed or attached to a review. ``results.json`` is written with NaN as
``null`` (strict JSON). All three are written atomically.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from graphpos.io.exports import write_atomically


@dataclass
class Table:
    header: list[str]
    rows: list[list[str]]
    caption: str = ""


@dataclass
class Figure:
    path: Path
    caption: str = ""


@dataclass
class Section:
    title: str
    blocks: list[Any] = field(default_factory=list)  # str (paragraph), Table, Figure
    level: int = 2

    def text(self, paragraph: str) -> "Section":
        self.blocks.append(paragraph)
        return self

    def table(self, header: list[str], rows: list[list[str]], caption: str = "") -> "Section":
        self.blocks.append(Table(header, rows, caption))
        return self

    def figure(self, png: Path, caption: str = "") -> "Section":
        self.blocks.append(Figure(Path(png), caption))
        return self


@dataclass
class Report:
    title: str
    sections: list[Section] = field(default_factory=list)

    def section(self, title: str, level: int = 2) -> Section:
        sec = Section(title, level=level)
        self.sections.append(sec)
        return sec

    # -- markdown -------------------------------------------------------------
    def markdown(self, folder: Path) -> str:
        out = [f"# {self.title}", ""]
        for sec in self.sections:
            out += ["#" * sec.level + " " + sec.title, ""]
            for block in sec.blocks:
                if isinstance(block, Table):
                    if block.caption:
                        out += [block.caption, ""]
                    out.append("| " + " | ".join(block.header) + " |")
                    out.append("|" + "|".join("---" for _ in block.header) + "|")
                    out += ["| " + " | ".join(row) + " |" for row in block.rows]
                elif isinstance(block, Figure):
                    path = block.path
                    rel = path.relative_to(folder) if path.is_relative_to(folder) else path
                    out.append(f"![{path.stem}]({rel.as_posix()})")
                    if block.caption:
                        out += ["", f"*{block.caption}*"]
                else:
                    out.append(block)
                out.append("")
        return "\n".join(out)

    # -- html -----------------------------------------------------------------
    def html(self) -> str:
        body = [f"<h1>{html.escape(self.title)}</h1>"]
        for sec in self.sections:
            level = min(sec.level, 6)
            body.append(f"<h{level}>{html.escape(sec.title)}</h{level}>")
            for block in sec.blocks:
                if isinstance(block, Table):
                    cap = f"<caption>{html.escape(block.caption)}</caption>" if block.caption else ""
                    head = "".join(f"<th>{html.escape(h)}</th>" for h in block.header)
                    rows = "".join(
                        "<tr>" + "".join(f"<td{_align(c)}>{html.escape(c)}</td>" for c in row) + "</tr>"
                        for row in block.rows
                    )
                    body.append(f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
                elif isinstance(block, Figure):
                    data = base64.b64encode(block.path.read_bytes()).decode()
                    cap = f"<figcaption>{html.escape(block.caption)}</figcaption>" if block.caption else ""
                    body.append(f'<figure><img alt="{html.escape(block.path.stem)}" '
                                f'src="data:image/png;base64,{data}"/>{cap}</figure>')
                else:
                    body.append(f"<p>{html.escape(block)}</p>")
        style = (
            "body{font-family:system-ui,sans-serif;max-width:1400px;margin:2em auto;padding:0 1em;color:#222}"
            "table{border-collapse:collapse;margin:1em 0;font-size:0.9em}"
            "td,th{border:1px solid #bbb;padding:3px 8px;text-align:left;vertical-align:top}"
            "th{background:#eee;vertical-align:bottom}td.num{text-align:right}"
            "caption{text-align:left;font-style:italic;padding:4px 0}"
            "img{max-width:100%}figure{margin:1em 0}figcaption{font-style:italic;color:#555;font-size:0.9em}"
            "h3{margin-top:1.5em}"
        )
        return (
            "<!DOCTYPE html><html><head><meta charset='utf-8'>"
            f"<title>{html.escape(self.title)}</title><style>{style}</style></head><body>"
            + "\n".join(body)
            + "</body></html>\n"
        )

    def write(self, folder: Path) -> tuple[Path, Path]:
        """Write ``report.md`` and ``report.html`` into ``folder``."""
        folder = Path(folder)
        md = write_atomically(folder / "report.md", self.markdown(folder))
        page = write_atomically(folder / "report.html", self.html())
        return md, page


def _align(cell: str) -> str:
    """Figures (``1.23``, ``−4 %``, ``0.5 ± 0.1 / 1.2``, an en dash) right-aligned; words left."""
    return ' class="num"' if re.match(r"^[-−–+]?(\d|–$)", cell.strip()) else ""


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, (str, int, bool)):
        return value
    return repr(value)


def write_json(path: Path, payload: Any) -> Path:
    """Strict JSON (NaN and infinities as null), written atomically."""
    return write_atomically(path, json.dumps(_jsonable(payload), indent=1, allow_nan=False) + "\n")


def fmt(value: Any, digits: int = 2) -> str:
    """A figure for a table cell: fixed digits, an en dash for missing."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    return "–" if not math.isfinite(v) else f"{v:.{digits}f}"


def mean_spread(values: list[float], digits: int = 2) -> str:
    """``mean ± std`` over seeds (just the value for one seed; en dash for none)."""
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return "–"
    if len(vals) == 1:
        return fmt(vals[0], digits)
    return f"{np.mean(vals):.{digits}f} ± {np.std(vals):.{digits}f}"
