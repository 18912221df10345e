"""The relaxation's sparse solve on the map's junctions (bioslam.link_solve) against the
least-squares problem it stands for, solved densely."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bioslam.link_solve import _eliminate, solve_links


def dense_solution(src, dst, info, rel, n):
    """``min Σ (x_dst - x_src - rel)ᵀ W (x_dst - x_src - rel)`` with node ``n-1`` at zero,
    from its normal equations built link by link."""
    d = 1 if info.ndim == 1 else 2
    w = info.reshape(-1, d, d)
    r = rel.reshape(-1, d)
    lap = np.zeros((n * d, n * d))
    rhs = np.zeros(n * d)
    for e, (a, b) in enumerate(zip(src, dst, strict=True)):
        ia, ib = slice(a * d, a * d + d), slice(b * d, b * d + d)
        lap[ia, ia] += w[e]
        lap[ib, ib] += w[e]
        lap[ia, ib] -= w[e]
        lap[ib, ia] -= w[e]
        rhs[ib] += w[e] @ r[e]
        rhs[ia] -= w[e] @ r[e]
    free = (n - 1) * d
    x = np.linalg.solve(lap[:free, :free], rhs[:free]).reshape(n - 1, d)
    return x[:, 0] if d == 1 else x


def chain_map(n: int, loops: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A cognitive map's shape: a chain from the ground (node ``n-1``) through nodes
    0..n-2, loop links between nodes of its first 80 % (the rest a dangling tail), the
    first link repeated and one from a node to itself."""
    src = [n - 1, *range(n - 2)]
    dst = [0, *range(1, n - 1)]
    for _ in range(loops):
        a, b = rng.integers(0, max(int(0.8 * n), 2), 2)
        src.append(int(b))
        dst.append(int(a))
    src += [n - 1, 0]
    dst += [0, 0]
    return np.array(src), np.array(dst)


def random_information(rng: np.random.Generator, links: int, block: bool) -> np.ndarray:
    if not block:
        return rng.uniform(0.2, 5.0, links)
    a = rng.normal(size=(links, 2, 2))
    return a @ a.transpose(0, 2, 1) + 0.05 * np.eye(2)


@pytest.mark.parametrize("block", [False, True])
@pytest.mark.parametrize(("n", "loops"), [(2, 0), (3, 1), (60, 8), (600, 40)])
def test_the_solve_on_the_junctions_is_the_whole_least_squares_solution(n, loops, block):
    rng = np.random.default_rng(n + loops)
    src, dst = chain_map(n, loops, rng)
    info = random_information(rng, src.size, block)
    rel = rng.normal(size=src.size if not block else (src.size, 2))
    expected = dense_solution(src, dst, info, rel, n)
    assert np.allclose(solve_links(src, dst, info, rel, n), expected, atol=1e-9)


def test_a_chain_hanging_off_the_ground_is_its_links_composed_and_needs_no_factorisation():
    n = 50
    src, dst = np.r_[n - 1, np.arange(n - 2)], np.r_[0, np.arange(1, n - 1)]
    rel = np.random.default_rng(3).normal(size=(src.size, 2))
    info = np.tile(np.diag([4.0, 0.5]), (src.size, 1, 1))
    kept, *_ = _eliminate(n, src, dst, info, rel)
    assert list(kept) == [n - 1]  # only the ground is left to solve
    assert np.allclose(solve_links(src, dst, info, rel, n), np.cumsum(rel, axis=0))


def test_a_loops_misclosure_is_shared_in_proportion_to_each_links_variance():
    # ground -> 0 -> 1 -> ground: offsets that should sum to zero round the loop sum to 0.6
    src, dst = np.array([2, 0, 1]), np.array([0, 1, 2])
    rel = np.array([1.0, 1.0, -1.4])
    variance = np.array([1.0, 2.0, 3.0])
    x = solve_links(src, dst, 1.0 / variance, rel, 3)
    share = 0.6 * np.cumsum(variance) / variance.sum()
    assert np.allclose(x, [1.0 - share[0], 2.0 - share[1]])


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 40),
    extra=st.lists(st.tuples(st.integers(0, 39), st.integers(0, 39)), max_size=30),
    block=st.booleans(),
    seed=st.integers(0, 2**31 - 1),
)
def test_any_connected_map_solves_as_the_dense_system(n, extra, block, seed):
    rng = np.random.default_rng(seed)
    parent = [int(rng.integers(k + 1, n)) for k in range(n - 1)]  # a tree to the ground
    src = np.array(list(range(n - 1)) + [a % n for a, _ in extra], dtype=np.int64)
    dst = np.array(parent + [b % n for _, b in extra], dtype=np.int64)
    info = random_information(rng, src.size, block)
    rel = rng.normal(size=src.size if not block else (src.size, 2))
    expected = dense_solution(src, dst, info, rel, n)
    assert np.allclose(solve_links(src, dst, info, rel, n), expected, atol=1e-8)
