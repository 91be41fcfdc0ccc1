"""host_tools.plan.reach2's passes as loops over arrays: compiled by numba and as plain Python they agree, the
polygon clipping finds the vertices a brute-force enumeration finds, and an empty controllable set is reported
at the grid point where it is empty."""
from __future__ import annotations

import importlib.util
import itertools
import sys

import numpy as np
import pytest

from host_tools.plan import reach2
from host_tools.plan.example import report_problem
from host_tools.plan.reach import plan_reach

HAVE_NUMBA = importlib.util.find_spec("numba") is not None
needs_numba = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed (the compiled passes are optional)")


def _passes_input(problem, gridpoints: int, monkeypatch) -> tuple:
    """What `plan_reach` hands `reach2.backward` for an order-2 plan: the rows, the steps, each point's x bound."""
    seen, backward = [], reach2.backward
    monkeypatch.setattr(reach2, "backward", lambda *given: seen.append(given) or backward(*given))
    plan_reach(problem, gridpoints, order=2)
    return seen[0]


@needs_numba
def test_compiled_and_plain_passes_agree(monkeypatch):
    rows, h, x_max = _passes_input(report_problem(), 20, monkeypatch)
    compiled = reach2._passes()
    assert compiled.backward is not reach2._backward_pass
    plain_k, plain_first, plain_count, plain_spans, plain_failed = reach2._backward_pass(*rows, h, x_max)
    kept, first, count, spans, failed = compiled.backward(*rows, h, x_max)
    assert failed == plain_failed == -1
    assert np.array_equal(first, plain_first) and np.array_equal(count, plain_count)
    used = first[0] + count[0]
    assert np.array_equal(kept[:used], plain_k[:used]) and np.array_equal(spans, plain_spans)
    x, u = compiled.forward(*rows, h, kept, first, count)
    plain_x, plain_u = reach2._forward_pass(*rows, h, kept, first, count)
    assert np.array_equal(x, plain_x) and np.array_equal(u, plain_u)
    assert np.all(np.isfinite(x)) and np.all(x >= 0) and x[0] == x[-1] == 0.0


def test_without_numba_the_passes_are_the_plain_functions(monkeypatch):
    monkeypatch.setitem(sys.modules, "numba", None)                 # as if it were not installed
    reach2._passes.cache_clear()
    try:
        assert reach2._passes() == (reach2._backward_pass, reach2._forward_pass)
    finally:
        reach2._passes.cache_clear()


def _brute_force_vertices(rows: np.ndarray, x_max: float) -> np.ndarray:
    """Every intersection of two of the rows' lines and the box's that satisfies all of them (to 1e-9), each once."""
    box = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, x_max], [0.0, 1.0, reach2._BOX_U], [0.0, -1.0, reach2._BOX_U]])
    lines = np.concatenate([rows, box])
    found = []
    for a, b in itertools.combinations(lines, 2):
        m = np.array([a[:2], b[:2]])
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        p = np.linalg.solve(m, [a[2], b[2]])
        if np.all(lines[:, :2] @ p - lines[:, 2] <= 1e-9 * (1 + np.abs(lines[:, 2]))):
            if not any(np.allclose(p, q, rtol=1e-9, atol=1e-9) for q in found):
                found.append(p)
    return np.array(found)


def test_polygon_has_the_vertices_of_a_brute_force_enumeration():
    """Tangents of an ellipse about (3, 0) in random order, with redundant rows among them, in 0 <= x <= 5. Two
    of the tangents meet at 0.3 degrees: clipped from a box a million wide, their vertex is found to 5e-9."""
    rng = np.random.default_rng(5)
    angles = rng.uniform(0, 2 * np.pi, 14)
    normal = np.stack([np.cos(angles), 4 * np.sin(angles)], axis=1)
    offset = normal @ [3.0, 0.0] + np.hypot(2.5 * np.cos(angles), 4 * np.sin(angles))
    redundant = np.stack([normal[:6, 0], normal[:6, 1], offset[:6] + rng.uniform(0.1, 2.0, 6)], axis=1)
    rows = np.concatenate([np.stack([normal[:, 0], normal[:, 1], offset], axis=1), redundant])
    rows = rows[rng.permutation(len(rows))]
    rows /= np.abs(rows[:, :2]).max(axis=1, keepdims=True)
    vertices, labels = reach2.polygon(rows, 5.0)
    expected = _brute_force_vertices(rows, 5.0)
    assert len(vertices) == len(expected) >= 8
    for p in expected:
        assert np.min(np.hypot(*(vertices - p).T)) < 1e-7
    edges = np.stack([vertices, np.roll(vertices, -1, axis=0)], axis=1)   # edge k: from vertex k to vertex k + 1
    for row, ends in zip(labels, edges):
        if row >= 0:
            assert np.all(np.abs(ends @ rows[row, :2] - rows[row, 2]) < 1e-7)
    assert -1 in labels and len(set(labels)) == len(labels)                  # x <= 5 is an edge


def test_polygon_of_contradicting_rows_is_empty():
    vertices, labels = reach2.polygon(np.array([[1.0, 0.0, 1.0], [-1.0, 0.0, -2.0], [0.0, 1.0, 3.0]]), 5.0)
    assert len(vertices) == len(labels) == 0


def _interval_rows(n: int) -> list[np.ndarray]:
    """Rows alpha x_i + beta u_i + delta u_{i+1} <= gamma for n intervals: |u_i| <= 1, |u_{i+1}| <= 1, x_i <= 4,
    and one free column (0 <= 1) for a test to fill."""
    alpha = np.tile([0.0, 0.0, 0.0, 0.0, 1.0, 0.0], (n, 1))
    beta = np.tile([1.0, -1.0, 0.0, 0.0, 0.0, 0.0], (n, 1))
    delta = np.tile([0.0, 0.0, 1.0, -1.0, 0.0, 0.0], (n, 1))
    gamma = np.tile([1.0, 1.0, 1.0, 1.0, 4.0, 1.0], (n, 1))
    return [alpha, beta, delta, gamma]


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=needs_numba)])
def test_an_empty_controllable_set_is_reported_where_it_is_empty(compiled):
    n, h, x_max = 8, np.full(8, 0.1), np.full(9, 10.0)
    passes = reach2._passes() if compiled else reach2._Passes(reach2._backward_pass, reach2._forward_pass)
    rows = _interval_rows(n)
    sets, spans, failed = reach2.backward(rows, h, x_max)
    assert failed == -1 and len(sets) == n + 1 and np.all(spans[:-1, 1] > 0)
    e, f, g = sets[0]
    assert np.array_equal(e[-4:], [-1.0, 1.0, 0.0, 0.0]) and g[-3] == 10.0     # the box's rows last
    unreachable = [r.copy() for r in rows]                           # x_5 >= 5 against x_5 <= 4
    unreachable[0][5, 5], unreachable[3][5, 5] = -1.0, -5.0
    impossible = [r.copy() for r in rows]                            # 0 <= -1 on interval 3
    impossible[3][3, 5] = -1.0
    for wrong, at in ((unreachable, 5), (impossible, 3)):
        kept, first, count, spans, failed = passes.backward(*wrong, h, x_max)
        assert failed == at and np.all(spans[at + 1:-1, 1] > 0) and np.all(spans[:at + 1] == 0)
        assert reach2.backward(wrong, h, x_max)[0] is None


def test_kept_rows_grow_beyond_the_first_guess_and_clip_beyond_its_buffers():
    kept, used = reach2._kept(np.empty((2, 3)), 0, np.arange(3.0).reshape(1, 3))
    kept, used = reach2._kept(kept, used, np.arange(3.0, 18.0).reshape(5, 3))
    assert used == 6 and len(kept) >= 6 and np.array_equal(kept[:6].ravel(), np.arange(18.0))
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    out, labels, made = reach2._clip(square, np.arange(4), 4, 1.0, 1.0, 1.5, 9, np.empty((0, 2)), np.empty(0, int))
    assert made == 5
    assert np.allclose(out[:made], [[0, 0], [1, 0], [1, 0.5], [0.5, 1], [0, 1]])
    assert list(labels[:made]) == [0, 1, 9, 2, 3]
