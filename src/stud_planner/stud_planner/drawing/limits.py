"""The work budget of reading a drawing: how much block expansion a DXF may ask for.

A DXF is a program as much as a picture: ten block levels, each inserting the level below ten times,
are 10^10 circles in a 3 KB file, and a MINSERT of 10^6 x 10^6 cells is one entity. A weld cell reads
drawings from e-mail and USB sticks, so the reader counts what a block reference would produce
*before* it produces it, and stops at :class:`DrawingLimits` with :class:`DrawingLimitError`: one line
naming the block, its nesting level and the count, in a fraction of a second and a bounded amount of
memory (about 100 bytes per expanded entity: ``max_expanded_entities`` bounds it).

The defaults are far beyond any real drawing: the largest stud layouts are bridges of 250,000 studs
(8x fewer than ``max_expanded_entities``, however they are drawn), real block nesting is a few levels
deep, and a MINSERT is a grid of tens to thousands of cells. A genuine drawing beyond one is read by
raising that limit: ``--max-expanded-entities N`` (and the like) for ``drawing_inspect`` and ``plan``,
the parameters ``drawing_limits.<name>`` for the drawing node, ``--var 'drawing_limits={name: N}'``
for the cell.

Pure Python, no ROS (the drawing node declares one parameter per field).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field, fields, replace
from typing import Any

from stud_planner.drawing.layout_types import DrawingError


def _limit(default: int, text: str, minimum: int = 1) -> Any:
    return field(default=default, metadata={"text": text, "min": minimum})


@dataclass(frozen=True)
class DrawingLimits:
    """The work a drawing may ask of the reader; crossing one is a :class:`DrawingLimitError`."""

    #: Blocks nested deeper than this (modelspace inserts level 1, which inserts level 2, ...).
    max_block_depth: int = _limit(32, "deepest block nesting (modelspace's INSERTs are level 1)")
    #: Circles and labels that block references may produce in all, counted over every placement
    #: at every level (a block placed k times with n entities adds k x n) before they are produced.
    max_expanded_entities: int = _limit(
        2_000_000, "circles and labels block references may produce in all, every level counted")
    #: Grid cells of all MINSERT entities together (rows x columns with a non-zero spacing).
    max_minsert_cells: int = _limit(1_000_000, "cells of all MINSERT grids together (rows x columns)")
    #: Characters of one TEXT, MTEXT or ATTRIB entity.
    max_text_chars: int = _limit(1_000_000, "characters of one TEXT, MTEXT or ATTRIB entity")

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int) or value < f.metadata["min"]:
                raise ValueError(f"drawing limit {f.name}={value!r}: expected an integer >= {f.metadata['min']}")

    def with_changes(self, **changes: int) -> "DrawingLimits":
        """A copy with ``changes`` (validated)."""
        return replace(self, **changes)

    @staticmethod
    def describe() -> dict[str, tuple[int, str]]:
        """``{name: (default, description)}`` for every limit (parameters, CLI flags, docs)."""
        defaults = DrawingLimits()
        return {f.name: (int(getattr(defaults, f.name)), str(f.metadata["text"])) for f in fields(DrawingLimits)}


class DrawingLimitError(DrawingError):
    """A drawing that asks for more work than :class:`DrawingLimits` allows. ``limit`` is the field
    crossed, ``count`` what the drawing asked for."""

    def __init__(self, message: str, limit: str, count: int) -> None:
        super().__init__(message)
        self.limit = limit
        self.count = count


# -- the command-line side (drawing_inspect, plan) ---------------------------------------------------
def add_limit_arguments(parser: argparse.ArgumentParser) -> None:
    """``--max-block-depth N`` ... one option per :class:`DrawingLimits` field."""
    for name, (default, text) in DrawingLimits.describe().items():
        parser.add_argument(f"--{name.replace('_', '-')}", type=int, default=default, metavar="N",
                            help=f"drawing limit: {text} (default {default:,}); raise it for a genuine drawing "
                                 "beyond it")


def limits_from_args(args: argparse.Namespace) -> DrawingLimits:
    """The :class:`DrawingLimits` of :func:`add_limit_arguments`'s options (ValueError when one is invalid)."""
    return DrawingLimits(**{name: getattr(args, name) for name in DrawingLimits.describe()})


def cli_hint(exc: DrawingError) -> str:
    """The option that raises the limit ``exc`` crossed (empty for any other error)."""
    if isinstance(exc, DrawingLimitError):
        return f" (a genuine drawing? raise it with --{exc.limit.replace('_', '-')})"
    return ""
