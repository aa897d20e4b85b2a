"""What CAD does not show is not part of the drawing: whether an entity is visible, decided in one place.

Invisible entities (DXF group 60) and entities on layers that are frozen or off are left out, and
counted here for the reader's warnings. A frozen INSERT hides all of its block; an off one only
what inherits its layer (layer "0" inside the block), which :meth:`Visibility.inherited_hidden`
checks once the block's layers are resolved. ``include_hidden_layers`` treats every layer as shown
(invisible entities stay left out). The ezdxf objects (:meth:`Visibility.entity_shown`) and the
arrays of :mod:`stud_planner.drawing.plain_circles` (:meth:`Visibility.plain_circles_shown`) go
through the same rules.
"""
from __future__ import annotations

from collections import Counter
from typing import Any, Iterable

import numpy as np


class Visibility:
    """The hidden layers of a document and the count of what was left out (for the warnings)."""

    def __init__(self, layers: Iterable[Any], include_hidden_layers: bool = False) -> None:
        #: case-folded layer name -> "frozen" or "off"
        self.hidden_layers: dict[str, str] = {}
        for lay in layers if not include_hidden_layers else ():
            state = "frozen" if lay.is_frozen() else "off" if lay.is_off() else None
            if state:
                self.hidden_layers[lay.dxf.name.casefold()] = state
        self.invisible: Counter = Counter()  # entity type -> count
        self.on_hidden_layer: Counter = Counter()  # (layer, entity type) -> count

    def layer_state(self, layer: str) -> str | None:
        """"frozen", "off", or None for a shown layer."""
        return self.hidden_layers.get(layer.casefold())

    def entity_shown(self, e: Any, dxftype: str, layer: str, in_block: bool) -> bool:
        """Whether CAD shows entity ``e`` (on its own ``layer``); counts it when not."""
        if e.dxf.get("invisible", 0):
            self.invisible[dxftype] += 1
            return False
        state = self.layer_state(layer)
        # layer "0" in a block inherits the INSERT's layer: decided by inherited_hidden
        if state and (dxftype != "INSERT" or state == "frozen") and not (in_block and layer == "0"):
            self.on_hidden_layer[(layer, dxftype)] += 1
            return False
        return True

    def plain_circles_shown(self, layers: np.ndarray, names: Iterable[str], invisible: np.ndarray) -> np.ndarray:
        """:meth:`entity_shown` for modelspace CIRCLE entities as arrays: ``layers`` (object array),
        ``names`` its distinct values, ``invisible`` the group 60 flags. Returns the shown ones (bool)."""
        if invisible.any():
            self.invisible["CIRCLE"] += int(np.count_nonzero(invisible))
        visible = ~invisible
        state = {lay: self.layer_state(lay) for lay in names}
        hidden = visible & np.array([bool(state[lay]) for lay in layers.tolist()], dtype=bool)
        for lay in set(layers[hidden].tolist()):
            self.on_hidden_layer[(lay, "CIRCLE")] += int(np.count_nonzero(hidden & (layers == lay)))
        return visible & ~hidden

    def inherited_hidden(self, layers: np.ndarray) -> np.ndarray:
        """Circles (resolved ``layers``, object array) on a hidden layer: those drawn on layer "0" in a
        block placed by an INSERT on an off layer. Counts them; returns the mask."""
        hidden_names = {lay for lay in set(layers.tolist()) if lay.casefold() in self.hidden_layers}
        hidden = np.isin(layers, list(hidden_names))
        for lay in hidden_names:
            self.on_hidden_layer[(lay, "CIRCLE")] += int(np.count_nonzero(layers == lay))
        return hidden

    def hidden_circles(self) -> int:
        """Circles left out for a frozen or off layer."""
        return int(sum(n for (_, t), n in self.on_hidden_layer.items() if t == "CIRCLE"))

    def warnings(self, file_name: str) -> list[str]:
        """One line for the invisible entities, one for those on hidden layers (when there are any)."""
        warns = []
        if self.invisible:
            what = ", ".join(f"{n} {t}" for t, n in sorted(self.invisible.items()))
            warns.append(f"{file_name}: invisible entities (DXF group 60) skipped, as CAD does not show them: {what}")
        if self.on_hidden_layer:
            per_layer: dict[str, Counter] = {}
            for (lay, t), n in self.on_hidden_layer.items():
                per_layer.setdefault(lay, Counter())[t] += n
            what = "; ".join(f"{lay} ({self.hidden_layers[lay.casefold()]}): "
                             + ", ".join(f"{n} {t}" for t, n in sorted(c.items()))
                             for lay, c in sorted(per_layer.items(), key=lambda kv: kv[0].casefold()))
            warns.append(f"{file_name}: entities on frozen or off layers skipped, as CAD does not show them: {what}")
        return warns
