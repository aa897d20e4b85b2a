"""Which layers a rule means: layer names or fnmatch patterns, matched case-insensitively (the stud
layers, the mark layer). Whether CAD shows a layer is :mod:`.visibility`."""
from __future__ import annotations

import fnmatch
from typing import Callable, Sequence

__all__ = ["format_patterns", "layer_matcher"]


def layer_matcher(patterns: str | Sequence[str]) -> Callable[[str], bool]:
    """A test ``layer name -> bool`` for the names or fnmatch patterns ``patterns`` (case-insensitive)."""
    pats = [patterns] if isinstance(patterns, str) else list(patterns)
    pats = [p.casefold() for p in pats if p]

    def match(layer: str) -> bool:
        lay = layer.casefold()
        # the exact name first: AutoCAD allows [ ] in layer names, which fnmatch reads as a class
        return any(lay == p or fnmatch.fnmatchcase(lay, p) for p in pats)

    return match


def format_patterns(patterns: str | Sequence[str]) -> str:
    """``patterns`` for a message: ``"STUDS, STUDS_*"``."""
    return ", ".join([patterns] if isinstance(patterns, str) else list(patterns))
