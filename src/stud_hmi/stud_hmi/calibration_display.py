"""The calibration display of the HMI, ROS-free: the hand-eye each node reports in use
(``/calibration/hand_eye``, HandEyeInUse.summary() as JSON), one line of text for it, and the
alarm when the nodes use different ones (the ``calibration`` field of the ``status`` message)."""
from __future__ import annotations

import math
import os

from stud_hmi.alarms import Code


def same_hand_eye(a: dict, b: dict, tol_m: float = 1e-4, tol_deg: float = 0.01) -> bool:
    """Whether two hand-eye summaries (``xyz_m``, ``rpy_deg``) agree within ``tol_m`` [m] and ``tol_deg`` [deg]."""
    try:
        return (all(abs(x - y) <= tol_m for x, y in zip(a["xyz_m"], b["xyz_m"], strict=True))
                and all(abs(x - y) <= tol_deg for x, y in zip(a["rpy_deg"], b["rpy_deg"], strict=True)))
    except (KeyError, TypeError, ValueError):
        return False


def hand_eye_text(s: dict) -> str:
    """One line: where the hand-eye comes from and its values."""
    xyz = ", ".join(f"{v * 1000:.1f}" for v in s.get("xyz_m") or [])
    rpy = ", ".join(f"{v:.2f}" for v in s.get("rpy_deg") or [])
    if s.get("source") == "file":
        rms = s.get("position_rms_mm")
        extra = f", residual {rms:.2f} mm" if isinstance(rms, (int, float)) and math.isfinite(rms) else ""
        return (f"file {os.path.basename(s.get('path') or '')} ({s.get('date') or 'undated'}{extra}): "
                f"xyz [{xyz}] mm, rpy [{rpy}]°")
    return f"typed values: xyz [{xyz}] mm, rpy [{rpy}]°"


class HandEyeDisplay:
    """The hand-eye summaries of the nodes that publish one, in order of arrival."""

    def __init__(self) -> None:
        self._by_node: dict[str, dict] = {}  # publishing node -> summary

    def update(self, node: str, summary: dict) -> dict[tuple[str, str], str]:
        """One node's summary; returns the alarm causes of the calibration scope (none while all agree)."""
        self._by_node[node] = summary
        first = next(iter(self._by_node.values()))
        differ = [n for n, s in self._by_node.items() if not same_hand_eye(first, s)]
        causes = {}
        if differ:
            causes[Code.HAND_EYE, "calibration"] = "; ".join(
                f"{n}: {hand_eye_text(s)}" for n, s in sorted(self._by_node.items()))
        return causes

    def message(self) -> dict | None:
        """The hand-eye in use (the first node's; ``agree`` false when nodes differ)."""
        if not self._by_node:
            return None
        first = next(iter(self._by_node.values()))
        return {**first, "text": hand_eye_text(first), "nodes": sorted(self._by_node),
                "agree": all(same_hand_eye(first, s) for s in self._by_node.values())}
