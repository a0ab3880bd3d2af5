"""The report as a document: Markdown text with linked figures, rendered to self-contained HTML; the one
number format and table layout every section uses."""

from __future__ import annotations

import base64
import json
import math
import os
import re
from pathlib import Path

import markdown


def fmt(value: object, digits: int = 3) -> str:
    """The one number format of the report (tests parse it back): fixed decimals, '–' for missing/NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if isinstance(value, int):  # and bool
        return str(value)
    return f"{float(value):.{digits}f}"


def table(headers: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def read_json(path: Path) -> dict:
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing; run the stage that writes it first (dvc repro)")
    return json.loads(path.read_text())


def slug(title: str) -> str:
    """A heading's anchor as GitHub makes it, and as the HTML makes it (it calls this): lower case, punctuation
    dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")


def contents(markdown_text: str) -> str:
    """Every second-level heading of ``markdown_text`` as a list of links to its anchor."""
    titles = [line[3:].strip() for line in markdown_text.splitlines() if line.startswith("## ")]
    return "**Contents**\n\n" + "\n".join(f"- [{t}](#{slug(t)})" for t in titles)


class Report:
    """Markdown text plus the figures it links, built section by section."""

    def __init__(self, root: Path, out_dir: Path):
        self.root, self.out_dir = root, out_dir
        self.parts: list[str] = []
        self.figures: list[Path] = []
        self.contents_at: int | None = None

    def add_contents(self) -> None:
        """Here: the list of every section, linked (filled in when the report is read)."""
        self.contents_at = len(self.parts)

    def add(self, text: str) -> None:
        self.parts.append(text.strip())

    def figure(self, path: Path, caption: str) -> None:
        """Link a figure if the run produced it; a missing figure is named, not silently dropped."""
        if not path.exists():
            self.add(f"*Figure missing: `{path.relative_to(self.root)}` ({caption}).*")
            return
        self.figures.append(path)
        self.add(f"![{caption}]({Path(os.path.relpath(path, self.out_dir)).as_posix()})\n\n*{caption}*")

    @property
    def markdown(self) -> str:
        parts = list(self.parts)
        if self.contents_at is not None:
            parts.insert(self.contents_at, contents("\n\n".join(parts[self.contents_at :])))
        return "\n\n".join(parts) + "\n"

    def html(self) -> str:
        body = markdown.markdown(
            self.markdown,
            extensions=["tables", "toc"],
            extension_configs={"toc": {"slugify": lambda value, _separator: slug(value)}},
        )

        def embed(match: re.Match) -> str:
            path = (self.out_dir / match.group(1)).resolve()
            data = base64.b64encode(path.read_bytes()).decode()
            return f'src="data:image/png;base64,{data}"'

        body = re.sub(r'src="([^"]+\.png)"', embed, body)
        style = (
            "body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;line-height:1.45}"
            "table{border-collapse:collapse;margin:1em 0;font-size:0.9em}td,th{border:1px solid #bbb;padding:3px 8px}"
            "th{background:#eee}img{max-width:100%}code{background:#f4f4f4}"
        )
        return (
            f'<!DOCTYPE html>\n<html><head><meta charset="utf-8"><title>uqdrive report</title>'
            f"<style>{style}</style></head><body>\n{body}\n</body></html>\n"
        )
