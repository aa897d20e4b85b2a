"""The order a station's studs are welded in: a short path through them in joint space.

Pure numpy. The cost of going from one stud to the next is the time of the synchronised joint
move between their approach joints at full speed, ``max_i |dq_i| / v_max_i`` (s): the slowest
joint decides, as on the controller (a speed percentage scales every move alike, so it does not
change the order). The path starts at the arm's current joints and, with ``q_end``, returns there
(the cell shoots the station again after its welds). Nearest neighbour, then 2-opt until no
reversal of a stretch shortens it. Every stud appears exactly once.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike


def joint_move_costs(Q_from: np.ndarray, Q_to: np.ndarray, max_speed_rad_s: ArrayLike) -> np.ndarray:
    """(N, M) full-speed move times (s) between joint vectors ``Q_from`` (N, 6) and ``Q_to`` (M, 6), rad."""
    A = np.atleast_2d(np.asarray(Q_from, dtype=np.float64))
    B = np.atleast_2d(np.asarray(Q_to, dtype=np.float64))
    v = np.asarray(max_speed_rad_s, dtype=np.float64)
    return np.max(np.abs(A[:, None, :] - B[None, :, :]) / v, axis=2)


def path_cost(order: Sequence[int], cost: np.ndarray, from_start: np.ndarray, to_end: np.ndarray | None) -> float:
    """Cost of visiting ``order`` from the start (and back to the end, if ``to_end`` is given)."""
    if len(order) == 0:
        return 0.0
    c = float(from_start[order[0]]) + sum(float(cost[a, b]) for a, b in zip(order[:-1], order[1:]))
    return c + (float(to_end[order[-1]]) if to_end is not None else 0.0)


def order_by_path(q_start: np.ndarray, Q: np.ndarray, max_speed_rad_s: ArrayLike,
                  q_end: np.ndarray | None = None, max_passes: int = 50) -> list[int]:
    """Indices of the studs' joint vectors ``Q`` (N, 6) in visiting order from ``q_start`` (6,):
    nearest neighbour, improved by 2-opt; ``q_end`` (6,): the path ends there (its last leg counts)."""
    Q = np.atleast_2d(np.asarray(Q, dtype=np.float64))
    n = len(Q)
    if n <= 1:
        return list(range(n))
    cost = joint_move_costs(Q, Q, max_speed_rad_s)
    from_start = joint_move_costs(np.asarray(q_start)[None, :], Q, max_speed_rad_s)[0]
    to_end = None if q_end is None else joint_move_costs(Q, np.asarray(q_end)[None, :], max_speed_rad_s)[:, 0]
    # Route over an extended matrix: node n is the start, node n + 1 the end (free when there is none).
    C = np.zeros((n + 2, n + 2))
    C[:n, :n] = cost
    C[n, :n] = C[:n, n] = from_start
    C[:n, n + 1] = C[n + 1, :n] = 0.0 if to_end is None else to_end
    left = set(range(n))
    route = [n]
    while left:
        here = route[-1]
        nxt = min(left, key=lambda j: (C[here, j], j))
        route.append(nxt)
        left.remove(nxt)
    route.append(n + 1)
    for _ in range(max_passes):
        improved = False
        for i in range(1, n):
            for j in range(i + 1, n + 1):
                a, b, c, d = route[i - 1], route[i], route[j], route[j + 1]
                if C[a, c] + C[b, d] < C[a, b] + C[c, d] - 1e-12:
                    route[i:j + 1] = route[i:j + 1][::-1]
                    improved = True
        if not improved:
            break
    return route[1:-1]
