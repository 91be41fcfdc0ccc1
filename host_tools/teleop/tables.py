"""Width-aware tables for teleop's output, drawn by rich as plain text lines.

`watch`, `box` and `params` lay their columns out here rather than by hand padding: rich measures
each cell, gives the columns the width the terminal has, and where a row is still too wide wraps
the cells marked `wrap` inside their own column (a parameter's description), never a line across
the edge of the terminal. The text is plain (no colour, no box characters) so that it reads the
same on a terminal, in a pipe and in a log.
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Sequence

from rich.console import Console as RichConsole
from rich.table import Table


@dataclass(frozen=True)
class Column:
    heading: str
    right: bool = False       # numbers: aligned on the right
    wrap: bool = False        # long text: wrapped inside the column; other columns are never wrapped


def table_lines(columns: Sequence[Column], rows: Sequence[Sequence[str]], width: int,
                headings: bool = True, indent: int = 0) -> list[str]:
    """`rows` laid out under `columns` in at most `width` characters, one space between columns (a heading may
    hold a line break: its unit below it). Where the columns that keep their cells whole cannot fit, every column
    wraps."""
    lines = _render(columns, rows, width - indent, headings, all_wrap=False)
    if max(map(len, lines), default=0) > width - indent:
        lines = _render(columns, rows, width - indent, headings, all_wrap=True)
    pad = " " * indent
    return [pad + line for line in lines]


def _render(columns: Sequence[Column], rows: Sequence[Sequence[str]], width: int, headings: bool,
            all_wrap: bool) -> list[str]:
    table = Table(box=None, show_header=headings, header_style=None, pad_edge=False, padding=(0, 1, 0, 0),
                  show_edge=False, expand=False)
    for column in columns:
        table.add_column(column.heading, justify="right" if column.right else "left", no_wrap=not (column.wrap or all_wrap),
                         overflow="fold", ratio=1 if column.wrap else None)
    for row in rows:
        table.add_row(*row)
    out = io.StringIO()
    console = RichConsole(file=out, width=max(1, width), color_system=None, force_terminal=False,
                          legacy_windows=False, emoji=False, markup=False, highlight=False)
    console.print(table)
    return [line.rstrip() for line in out.getvalue().split("\n")[:-1]]
