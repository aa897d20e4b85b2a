"""Stud order: nearest neighbour + 2-opt through the studs' joints; every stud exactly once."""
from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rm65_driver.kinematics.rm65 import JOINT_MAX_SPEED_DEG_S
from rm65_driver.weld.stud_order import joint_move_costs, order_by_path, path_cost

V = np.radians(JOINT_MAX_SPEED_DEG_S)


def _costs(q0, Q, q_end=None):
    cost = joint_move_costs(Q, Q, V)
    start = joint_move_costs(q0[None, :], Q, V)[0]
    end = None if q_end is None else joint_move_costs(Q, q_end[None, :], V)[:, 0]
    return cost, start, end


def test_move_cost_is_the_slowest_joints_time():
    c = joint_move_costs(np.zeros((1, 6)), np.radians([[18.0, 0, 45.0, 0, 0, 0]]), V)
    assert c.shape == (1, 1)
    np.testing.assert_allclose(c[0, 0], 0.2)  # 45 deg at 225 deg/s beats 18 deg at 180 deg/s (0.1 s)


def test_studs_along_a_line_given_shuffled_are_visited_in_line_order():
    line = np.zeros((8, 6))
    line[:, 0] = np.radians(np.arange(1, 9) * 5.0)
    shuffled = [5, 2, 7, 0, 3, 6, 1, 4]
    order = order_by_path(np.zeros(6), line[shuffled], V)
    assert [shuffled[i] for i in order] == list(range(8))


def test_a_closed_tour_back_to_the_start_is_optimal_on_a_small_ring():
    rng = np.random.default_rng(3)
    Q = rng.uniform(-1, 1, size=(7, 6))
    q0 = np.zeros(6)
    cost, start, end = _costs(q0, Q, q0)
    order = order_by_path(q0, Q, V, q_end=q0)
    best = min(path_cost(p, cost, start, end) for p in itertools.permutations(range(7)))
    assert path_cost(order, cost, start, end) <= best * 1.10  # 2-opt: within 10 % of the optimum here


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 12), st.integers(0, 10_000), st.booleans())
def test_every_stud_once_and_never_worse_than_the_given_order_or_nearest_neighbour(n, seed, closed):
    rng = np.random.default_rng(seed)
    Q = rng.uniform(-2, 2, size=(n, 6))
    q0 = rng.uniform(-2, 2, size=6)
    q_end = q0 if closed else None
    order = order_by_path(q0, Q, V, q_end=q_end)
    assert sorted(order) == list(range(n))
    if n:
        cost, start, end = _costs(q0, Q, q_end)
        assert path_cost(order, cost, start, end) <= path_cost(list(range(n)), cost, start, end) + 1e-9 or n <= 2
