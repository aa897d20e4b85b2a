"""How the arm gets from where it is to a stud the reach verdict accepted.

:meth:`~rm65_driver.weld.reach.Reach.stud` decides *whether* a stud can be welded, from the stud and the
cell alone. Which of its solutions the arm takes, and how it gets there, depends on where the arm
is: :func:`plan_move` prefers the rotation about the stud's axis and the joint solution nearest the
current joints (short moves, the wrist turned as little as possible) and checks that the joint
move there keeps tool tip and flange inside the workspace box. When no near solution has a clear
straight joint move, the verdict's own plan is taken and reached through safe intermediate poses
(the tool lifted or pulled in toward the arm's axis, the arm standing upright, the reference posture):
a stud the verdict accepted is not refused because of where the arm happened to stand.

Pure numpy; joints rad, poses 4x4 in the arm's base frame, m.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rm65_driver.weld.reach import Reach, StudReach

#: How many near solutions are tried before the verdict's own plan is taken.
MAX_NEAR_TRIES = 3
#: The tool is lifted this far above the higher of its start and the approach pose for a detour.
LIFT_M = 0.10
#: A detour may first pull the tool's tip toward the arm's axis to this fraction of its distance.
PULL_IN = 0.8
#: Joint-interpolated moves are checked at this many points.
PATH_SAMPLES = 16


@dataclass(frozen=True)
class Move:
    """The chosen plan of one stud: tool poses (4x4), joints (6,) rad, the rotation about the
    stud's axis (rad), and ``via``: joint waypoints (each (6,)) before the approach."""

    yaw_rad: float
    T_approach: np.ndarray
    T_contact: np.ndarray
    q_approach: np.ndarray
    q_contact: np.ndarray
    via: tuple[np.ndarray, ...] = ()


def joint_path_problem(reach: Reach, q_from: np.ndarray, q_to: np.ndarray, what: str,
                       world_T_base: np.ndarray | None = None) -> str:
    """Why the joint-interpolated move ``q_from`` -> ``q_to`` leaves the workspace box (world; "" if it does not)."""
    s = np.linspace(0.0, 1.0, PATH_SAMPLES)[1:, None]
    Q = np.asarray(q_from, dtype=np.float64) + s * (np.asarray(q_to, dtype=np.float64) - np.asarray(q_from))
    flanges = reach.kin.fk(Q)
    points = np.vstack([(flanges @ reach.tool_T)[:, :3, 3], flanges[:, :3, 3]])
    if world_T_base is not None:
        B = np.asarray(world_T_base, dtype=np.float64)
        points = points @ B[:3, :3].T + B[:3, 3]
    lo, hi = np.asarray(reach.config.workspace_min_m), np.asarray(reach.config.workspace_max_m)
    bad = np.any((points < lo - 1e-9) | (points > hi + 1e-9), axis=1)
    if not bad.any():
        return ""
    p = points[int(np.argmax(bad))]
    return (f"{what} leaves the workspace box at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m "
            f"(box {lo.tolist()}..{hi.tolist()} m)")


def _contact_of(reach: Reach, T_approach: np.ndarray) -> np.ndarray:
    """The contact pose on the approach pose's tool axis (z into the surface)."""
    T = T_approach.copy()
    T[:3, 3] = T_approach[:3, 3] + (reach.config.standoff_m + reach.config.plunge_m) * T_approach[:3, 2]
    return T


def _shifted(reach: Reach, q: np.ndarray, z: float | None = None, radial: float = 1.0) -> np.ndarray | None:
    """Joints with the tool's tip moved to height ``z`` (None: kept) and ``radial`` times its distance
    from the arm's axis, orientation kept, solved from ``q`` (None: not solvable)."""
    T = reach.kin.fk(q, reach.tool_T)
    T[:2, 3] *= radial
    if z is not None:
        T[2, 3] = z
    res = reach.kin.ik(T, q, tool=reach.tool_T, restarts=0)
    return res.q if res.success else None


def _upright(q: np.ndarray) -> np.ndarray:
    """The arm standing straight up, turned as at ``q`` (J1 and J6 kept): inside any sensible box."""
    out = np.zeros(6)
    out[0], out[5] = q[0], q[5]
    return out


def _straightened(q: np.ndarray, joints: tuple[int, ...]) -> np.ndarray:
    """``q`` with ``joints`` (0-based) at zero: one step of unfolding a folded arm."""
    out = np.array(q, dtype=np.float64)
    out[list(joints)] = 0.0
    return out


#: Unfolding steps tried at either end of a detour: the shoulder, the wrist, the elbow straightened.
_UNFOLD = ((1,), (3, 4), (2,))


def detour(reach: Reach, q_from: np.ndarray, q_to: np.ndarray,
           world_T_base: np.ndarray | None = None) -> tuple[tuple[np.ndarray, ...] | None, str]:
    """Joint waypoints between ``q_from`` and ``q_to`` whose every leg stays in the workspace box:
    () when the straight joint move does; (None, why) when no detour tried does. Tried, fewest
    waypoints first: the tool lifted straight up or pulled toward the arm's axis, or the shoulder,
    wrist or elbow straightened at either end, around the arm standing upright or the reference
    posture between them."""
    why = joint_path_problem(reach, q_from, q_to, "approach move", world_T_base)
    if not why:
        return (), ""
    tip_from = reach.kin.fk(q_from, reach.tool_T)[2, 3]
    tip_to = reach.kin.fk(q_to, reach.tool_T)[2, 3]
    z = min(max(tip_from, tip_to) + LIFT_M, reach.config.workspace_max_m[2] - 0.05)
    ends: list[list[list[np.ndarray]]] = []
    for q in (q_from, q_to):
        moved = (_shifted(reach, q, z=z), _shifted(reach, q, radial=PULL_IN), *(_straightened(q, j) for j in _UNFOLD))
        ends.append([[]] + [[w] for w in moved if w is not None])
    ref_from, ref_to = (reach.seeds(reach.kin.fk(q, reach.tool_T)[:3, 3])[0] for q in (q_from, q_to))
    middles = [[], [_upright(q_from)], [_upright(q_from), _upright(q_to)], [ref_from, ref_to]]
    tries = sorted(((a, m, b) for a in ends[0] for m in middles for b in ends[1]),
                   key=lambda t: len(t[0]) + len(t[1]) + len(t[2]))
    for a, m, b in tries:
        legs = [q_from, *a, *m, *b, q_to]
        if not any(joint_path_problem(reach, u, v, "detour", world_T_base) for u, v in zip(legs[:-1], legs[1:])):
            return tuple(np.asarray(q) for q in (*a, *m, *b)), ""
    return None, f"{why}, and no detour tried stays inside it"


def plan_move(reach: Reach, verdict: StudReach, q_current: np.ndarray,
              world_T_base: np.ndarray | None = None) -> tuple[Move | None, str]:
    """The plan for a stud ``verdict`` accepted (with the base at ``world_T_base``), from
    ``q_current`` (see the module docstring); (None, why) only when no detour keeps the arm inside
    the workspace box."""
    assert verdict.ok and verdict.T_approach is not None and verdict.q_approach is not None
    q_current = np.asarray(q_current, dtype=np.float64).reshape(6)
    options = verdict.options
    T_apps = np.array([o.T_approach for o in options])
    near_q, near_ok, _ = reach.solve(T_apps, q_current[None, :])
    signs = np.asarray(reach.config.preferred_joint_signs)
    ask = signs != 0

    def in_branch(q: np.ndarray) -> bool:
        return bool(np.all(np.sign(q[ask]) == signs[ask])) if ask.any() else True

    candidates = []
    for o, qs, ok in zip(options, near_q[:, 0], near_ok[:, 0]):
        if ok:
            candidates.append((qs, o))
        candidates.append((o.q_approach, o))
    candidates.sort(key=lambda c: (not in_branch(c[0]), float(np.linalg.norm(c[0] - q_current))))
    for q_app, o in candidates[:MAX_NEAR_TRIES]:
        T_con = _contact_of(reach, o.T_approach)
        if any(reach.position_problems(T_con[None], "contact pose", world_T_base)):
            continue
        if joint_path_problem(reach, q_current, q_app, "approach move", world_T_base):
            continue
        path, _why = reach.kin.linear_path(q_app, T_con, tool=reach.tool_T)
        if path is not None:
            return Move(o.yaw_rad, o.T_approach, T_con, q_app, path[-1]), ""
    assert verdict.T_contact is not None and verdict.q_contact is not None
    via, why = detour(reach, q_current, verdict.q_approach, world_T_base)
    if via is None:
        return None, why
    return Move(verdict.yaw_rad, verdict.T_approach, verdict.T_contact, verdict.q_approach, verdict.q_contact, via), ""


__all__ = ["Move", "detour", "joint_path_problem", "plan_move"]
