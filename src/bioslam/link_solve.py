"""The relaxation's sparse solve (the fixed point of the weighted Eq. 14), reduced to the
map's junctions.

Solving for the experiences' headings, or for their positions with the headings fixed, is one
weighted least-squares problem over the links, ``min Σ_e (x_t - x_s - r_e)ᵀ W_e (x_t - x_s -
r_e)``: its normal equations are a graph Laplacian (:func:`laplacian_lu`). Most experiences
of a cognitive map sit on chains, one link in from the experience before and one out to the
next, and the robot's newest ones on a dangling tail; only the places where loop links join
the chains have more. Such a problem is solved exactly on the junctions alone: a node with
two links is eliminated by joining them into one (links in series add their covariances, as
springs do), a node with one link follows its neighbour, and once the junctions are solved
the eliminated nodes are put back in the reverse order, each where its two links balance.
The solve runs after every closure and made the full system's slowest scans. On the map the
demo maze's 600 s route ends with (4145 experiences, 378 loop links) 728 junctions are left
to factorise, and a solve takes 6.3 ms against 14.0 ms with the whole Laplacian factorised
(medians of 20, ``python benchmarks/bench_pose_cells.py``); the two agree to 1e-10 m.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: below this determinant of a node's summed link information the node is kept, not
#: eliminated: its two links leave it free (zero weight), as the full system would
_SINGULAR = 1e-300

#: the operations :func:`_eliminate` records: a node that follows its one neighbour, or one
#: balanced between its two
_LEAF, _SERIES = 1, 2


def incidence_t(
    src: NDArray[np.int64], dst: NDArray[np.int64], v: FloatArray, n: int
) -> FloatArray:
    """Bᵀ v for the incidence matrix B (-1 at a link's source, +1 at its target)."""
    return np.bincount(dst, v, minlength=n) - np.bincount(src, v, minlength=n)


def laplacian_lu(
    src: NDArray[np.int64], dst: NDArray[np.int64], weights: FloatArray, n: int
) -> Any:
    """LU of the weighted graph Laplacian ``Bᵀ W B`` without its last node (the fixed
    ground). The loop links join nodes far apart in creation order, so a minimum-degree
    ordering is used: on the demo maze's final map (3163 nodes) it leaves 8x fewer non-zeros
    than the natural order and factorises in 4.3 instead of 12.7 ms."""
    # SciPy's sparse solver (20 MB) only where a map is solved: not by the odometry alone
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    rows = np.concatenate([src, dst, src, dst])
    cols = np.concatenate([src, dst, dst, src])
    vals = np.concatenate([weights, weights, -weights, -weights])
    lap = sp.csc_matrix((vals, (rows, cols)), shape=(n, n))[:-1, :-1]
    return splu(
        lap.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )  # fmt: skip


def block_laplacian_lu(
    src: NDArray[np.int64], dst: NDArray[np.int64], omega: FloatArray, n: int
) -> Any:
    """LU of the graph Laplacian with a 2x2 block ``omega[e]`` per link (x and y of node i at
    rows 2i, 2i+1), without its last node (the fixed ground); as :func:`laplacian_lu`."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    rows, cols, vals = [], [], []
    for a in range(2):
        for b in range(2):
            w = omega[:, a, b]
            for u, v, sign in ((src, src, 1.0), (dst, dst, 1.0), (src, dst, -1), (dst, src, -1)):
                rows.append(2 * u + a)
                cols.append(2 * v + b)
                vals.append(sign * w)
    lap = sp.csc_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(2 * n, 2 * n)
    )[:-2, :-2]
    return splu(
        lap.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )  # fmt: skip


def solve_links(
    src: NDArray[np.int64], dst: NDArray[np.int64], info: FloatArray, rel: FloatArray, n: int
) -> FloatArray:
    """The ``x`` of nodes ``0..n-2`` minimising ``Σ_e (x_dst - x_src - rel_e)ᵀ info_e (x_dst -
    x_src - rel_e)``, node ``n-1`` (the ground) held at zero; ``info`` (E,) with ``rel`` (E,)
    for a scalar per node (headings), or (E, 2, 2) with ``rel`` (E, 2) for a position. The
    same as factorising the whole Laplacian, on the junctions only (see the module)."""
    scalar = info.ndim == 1
    d = 1 if scalar else 2
    weights = np.ascontiguousarray(info, dtype=np.float64).reshape(-1, d, d)
    offsets = np.ascontiguousarray(rel, dtype=np.float64).reshape(-1, d)
    src = np.ascontiguousarray(src, dtype=np.int64)
    dst = np.ascontiguousarray(dst, dtype=np.int64)
    kept, ls, lt, lw, lr, ops, ends, gains, steps = _eliminate(n, src, dst, weights, offsets)
    x = np.zeros((n, d))
    if kept.size > 1:  # junctions besides the ground: solve them
        label = np.full(n, -1, dtype=np.int64)
        label[kept] = np.arange(kept.size)
        x[kept[:-1]] = factorised_solve(label[ls], label[lt], lw, lr, kept.size)
    _put_back(x, ops, ends, gains, steps)
    return x[:-1, 0] if scalar else x[:-1]


def factorised_solve(
    src: NDArray[np.int64], dst: NDArray[np.int64], info: FloatArray, rel: FloatArray, n: int
) -> FloatArray:
    """The same least-squares problem as :func:`solve_links`, ``info`` (E, d, d) and ``rel``
    (E, d) with d 1 or 2, solved by factorising its whole Laplacian (every node kept);
    returns (n-1, d)."""
    if info.shape[1] == 1:
        weights = info[:, 0, 0]
        lu = laplacian_lu(src, dst, weights, n)
        return lu.solve(incidence_t(src, dst, weights * rel[:, 0], n)[:-1])[:, None]
    lu = block_laplacian_lu(src, dst, info, n)
    flow = np.einsum("eij,ej->ei", info, rel)
    rhs = np.stack([incidence_t(src, dst, flow[:, k], n)[:-1] for k in range(2)], 1)
    return lu.solve(rhs.reshape(-1)).reshape(-1, 2)


@njit(cache=True, inline="always")
def _invert_into(m, out):
    """``out`` = the inverse of the 1x1 or 2x2 matrix ``m``, False where it is singular (by
    hand, into a buffer: the kernel below runs once per node, where a LAPACK call or an
    allocation costs more than the arithmetic)."""
    if m.shape[0] == 1:
        if abs(m[0, 0]) < _SINGULAR:
            return False
        out[0, 0] = 1.0 / m[0, 0]
        return True
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    if abs(det) < _SINGULAR:
        return False
    out[0, 0], out[0, 1] = m[1, 1] / det, -m[0, 1] / det
    out[1, 0], out[1, 1] = -m[1, 0] / det, m[0, 0] / det
    return True


@njit(cache=True, inline="always")
def _times_into(a, b, out):
    """``out`` = ``a @ b`` for the tiny matrices here."""
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            acc = 0.0
            for k in range(a.shape[1]):
                acc += a[i, k] * b[k, j]
            out[i, j] = acc


@njit(cache=True, inline="always")
def _link_into(node, s, t, r, e, out):
    """``out`` = the offset along link ``e`` of its other end from ``node`` (its sign by the
    link's direction); returns that end."""
    sign = 1.0 if s[e] == node else -1.0
    for i in range(out.shape[0]):
        out[i] = sign * r[e, i]
    return t[e] if s[e] == node else s[e]


@njit(cache=True, inline="always")
def _attach(link, node, head, nxt, end_link, n_ends):
    """Adds an end of ``link`` to ``node``'s list; returns the ends used."""
    end_link[n_ends] = link
    nxt[n_ends] = head[node]
    head[node] = n_ends
    return n_ends + 1


@njit(cache=True)
def _eliminate(n, src, dst, info, rel):
    """Eliminates every node but the ground (``n-1``) with one or two links, joining a
    node's two links into one. Returns the kept nodes (ascending, the ground last), the
    links left between them (ends, information, offset) and the operations in the order
    made: kind and node, its neighbours (``ends``), the gain that balances a node between
    two (``gains``) and its offsets (``steps``: from the first, and of the second from it)."""
    e_in, d = rel.shape[0], rel.shape[1]
    cap = 2 * e_in + 1
    s = np.empty(cap, np.int64)
    t = np.empty(cap, np.int64)
    w = np.empty((cap, d, d))
    r = np.empty((cap, d))
    alive = np.zeros(cap, np.bool_)
    head = np.full(n, -1, np.int64)  # each node's link ends as a linked list
    nxt = np.empty(2 * cap, np.int64)
    end_link = np.empty(2 * cap, np.int64)
    degree = np.zeros(n, np.int64)
    n_links = n_ends = 0
    for e in range(e_in):
        if src[e] == dst[e]:
            continue  # a link from a node to itself moves nothing
        s[n_links], t[n_links] = src[e], dst[e]
        for i in range(d):
            r[n_links, i] = rel[e, i]
            for j in range(d):
                w[n_links, i, j] = info[e, i, j]
        alive[n_links] = True
        n_ends = _attach(n_links, src[e], head, nxt, end_link, n_ends)
        n_ends = _attach(n_links, dst[e], head, nxt, end_link, n_ends)
        degree[src[e]] += 1
        degree[dst[e]] += 1
        n_links += 1
    ops = np.empty((2, n), np.int64)
    ends = np.empty((n, 2), np.int64)
    gains = np.zeros((n, d, d))
    steps = np.zeros((n, 2, d))
    total, inv, half = np.empty((d, d)), np.empty((d, d)), np.empty((d, d))
    gain, step_in, step_out = np.empty((d, d)), np.empty(d), np.empty(d)
    eliminated = np.zeros(n, np.bool_)
    stack = np.empty(3 * n, np.int64)  # each node once, and its two neighbours per operation
    top = n_ops = 0
    for v in range(n - 1):
        if degree[v] == 1 or degree[v] == 2:
            stack[top] = v
            top += 1
    while top > 0:
        top -= 1
        v = stack[top]
        if eliminated[v] or v == n - 1 or degree[v] < 1 or degree[v] > 2:
            continue
        end = head[v]
        while not alive[end_link[end]]:
            end = nxt[end]
        e1 = end_link[end]
        a = _link_into(v, s, t, r, e1, step_in)  # a's offset from v, for now
        for i in range(d):
            step_in[i] = -step_in[i]  # v's offset from a
        b = a
        if degree[v] == 2:
            end = nxt[end]
            while not alive[end_link[end]]:
                end = nxt[end]
            e2 = end_link[end]
            for i in range(d):
                for j in range(d):
                    total[i, j] = w[e1, i, j] + w[e2, i, j]
            if not _invert_into(total, inv):
                continue  # left free by its links: kept, as the whole system would
            b = _link_into(v, s, t, r, e2, step_out)
            _times_into(inv, w[e2], gain)
            alive[e2] = False
            if a != b:  # (else the joined link would run from a to itself: dropped)
                _times_into(w[e1], gain, half)
                s[n_links], t[n_links] = a, b
                for i in range(d):
                    r[n_links, i] = step_in[i] + step_out[i]
                    for j in range(d):
                        w[n_links, i, j] = 0.5 * (half[i, j] + half[j, i])
                alive[n_links] = True
                n_ends = _attach(n_links, a, head, nxt, end_link, n_ends)
                n_ends = _attach(n_links, b, head, nxt, end_link, n_ends)
                degree[a] += 1
                degree[b] += 1
                n_links += 1
            degree[b] -= 1
        alive[e1] = False
        degree[a] -= 1
        ops[0, n_ops] = _LEAF if degree[v] == 1 else _SERIES
        ops[1, n_ops] = v
        for i in range(d):
            steps[n_ops, 0, i], steps[n_ops, 1, i] = step_in[i], step_out[i]
            for j in range(d):
                gains[n_ops, i, j] = gain[i, j]
        ends[n_ops, 0], ends[n_ops, 1] = a, b
        eliminated[v] = True
        degree[v] = 0
        n_ops += 1
        for node in (a, b):
            if degree[node] == 1 or degree[node] == 2:
                stack[top] = node
                top += 1
    kept = np.flatnonzero(~eliminated)
    left = np.flatnonzero(alive[:n_links])
    return (
        kept, s[left], t[left], w[left], r[left], ops[:, :n_ops], ends[:n_ops],
        gains[:n_ops], steps[:n_ops],
    )


@njit(cache=True)
def _put_back(x, ops, ends, gains, steps):
    """Places the eliminated nodes, last eliminated first: a leaf at its neighbour plus its
    link, a node between two where its links balance (``x_a + r1 + G (x_b - x_a - r1 -
    r2)``, ``G = (W1 + W2)⁻¹ W2``)."""
    d = x.shape[1]
    gap = np.empty(d)
    for k in range(ops.shape[1] - 1, -1, -1):
        v, a, b = ops[1, k], ends[k, 0], ends[k, 1]
        for i in range(d):
            x[v, i] = x[a, i] + steps[k, 0, i]
        if ops[0, k] == _SERIES:
            for i in range(d):
                gap[i] = x[b, i] - x[v, i] - steps[k, 1, i]
            for i in range(d):
                for j in range(d):
                    x[v, i] += gains[k, i, j] * gap[j]
