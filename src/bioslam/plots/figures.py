"""The pipeline's figures: cognitive map, active view and position error over time (the paper's
Fig. 6), mapping progress (Fig. 5) and the occupancy map with the trajectory.

Each public function takes plain arrays, writes one PNG (atomically, so an interrupted run never
leaves a truncated picture) and returns its path. Figures are built on ``matplotlib.figure.Figure``
with the Agg canvas, never through ``pyplot``: no display, no global figure state, safe to call
from any thread.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Protocol

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from numpy.typing import ArrayLike, NDArray

from bioslam.io.jsonio import atomic_write_bytes
from bioslam.plots import GROUND_TRUTH

FloatArray = NDArray[np.float64]
Link = tuple[int, int, Any]
"""A cognitive-map link ``(from_node, to_node, kind)``; ``kind`` in ``LOOP_KINDS`` marks a
loop closure (a link to an experience created long before), anything else an ordinary link."""

LOOP_KINDS = frozenset({"loop", "loop_closure", "closure"})

Target = str | Path | BinaryIO
"""Where a figure goes: a PNG file (written atomically), or a binary stream that gets the
PNG's bytes (a child process drawing for the command, :mod:`bioslam.plots.worker`)."""


@dataclass
class FigureConfig:
    """Look of the figures.

    dpi: 120 gives ~1000 px wide panels, readable on screen and small on disk.
    panel_size: inches per map panel; the paper's Fig. 5 panels are square.
    max_map_pixels: an occupancy map larger than this (cells a side) is reduced by a whole
        factor before drawing (a wall stays drawn: each pixel is its block's highest
        probability); the map's panel is ~800 pixels wide, and matplotlib's working copies
        of a larger image cost tens of megabytes (a 1000 x 900-cell map: 25 MB).
    """

    dpi: int = 120
    panel_size: float = 4.5
    node_colour: str = "tab:blue"
    link_colour: str = "0.55"
    loop_colour: str = "tab:red"
    truth_colour: str = "0.2"
    odometry_colour: str = "tab:orange"
    unknown_colour: str = "#a7b4c2"
    max_map_pixels: int = 900


CONFIG = FigureConfig()


class OccupancyLike(Protocol):
    """What :func:`plot_occupancy` reads from ``bioslam.io.mapfile.OccupancyImage``."""

    occupancy: FloatArray
    resolution: float
    origin: tuple[float, float, float]


# --- helpers -------------------------------------------------------------------------------


def _save(fig: Figure, path: Target, dpi: int) -> Target:
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    if isinstance(path, (str, Path)):
        return atomic_write_bytes(path, buffer.getvalue())
    path.write(buffer.getvalue())
    return path


def _xy(points: ArrayLike | None, what: str) -> FloatArray:
    arr = np.asarray(points if points is not None else np.zeros((0, 2)), dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise ValueError(f"{what} must be an (N, 2) array of x, y, got shape {arr.shape}")
    return arr[:, :2]


def _split_links(links: Sequence[Link], n_nodes: int) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Link endpoints as (M, 2) indices and a loop-closure mask; bad indices name the link."""
    if len(links) == 0:
        return np.zeros((0, 2), dtype=np.intp), np.zeros(0, dtype=bool)
    ends = np.array([(int(a), int(b)) for a, b, _ in links], dtype=np.intp)
    bad = np.flatnonzero((ends < 0).any(axis=1) | (ends >= n_nodes).any(axis=1))
    if bad.size:
        k = int(bad[0])
        raise ValueError(
            f"link {k} {tuple(ends[k].tolist())} refers to a node outside 0..{n_nodes - 1}"
        )
    loops = np.array([kind in LOOP_KINDS for _, _, kind in links], dtype=bool)
    return ends, loops


def _draw_map(
    ax: Axes,
    nodes_xy: FloatArray,
    links: Sequence[Link],
    gt_xy: FloatArray | None = None,
    gt_label: str = GROUND_TRUTH,
) -> None:
    """Experience nodes, ordinary links, loop links on top, and the ground truth (or the
    reference called ``gt_label``) underneath."""
    cfg = CONFIG
    if gt_xy is not None and len(gt_xy):
        ax.plot(*gt_xy.T, color=cfg.truth_colour, lw=0.8, ls="--", alpha=0.6, label=gt_label)
    ends, loops = _split_links(links, len(nodes_xy))
    segments = nodes_xy[ends] if len(ends) else np.zeros((0, 2, 2))
    ax.add_collection(LineCollection(segments[~loops], colors=cfg.link_colour, linewidths=0.8))
    ax.scatter(*nodes_xy.T, s=3, color=cfg.node_colour, alpha=0.5, lw=0, zorder=3,
               label=f"{len(nodes_xy)} nodes")  # fmt: skip
    # A verified loop link joins two places a few centimetres apart: drawn as a line it would
    # hide under the nodes, so its ends are marked as well, on top of everything.
    ax.add_collection(
        LineCollection(segments[loops], colors=cfg.loop_colour, linewidths=1.6, zorder=4)
    )
    loop_ends = segments[loops].reshape(-1, 2)
    ax.scatter(*loop_ends.T, s=14, facecolors="none", edgecolors=cfg.loop_colour, lw=0.9,
               zorder=5, label=f"loop links ({int(loops.sum())})")  # fmt: skip
    _finish_map_axes(ax)


def _finish_map_axes(ax: Axes, adjustable: str = "datalim") -> None:
    ax.set_aspect("equal", adjustable=adjustable)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.autoscale_view()


def _limits(*point_sets: FloatArray) -> tuple[tuple[float, float], tuple[float, float]] | None:
    pts = [p for p in point_sets if len(p)]
    if not pts:
        return None
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    margin = 0.05 * max(float(np.max(hi - lo)), 1.0)
    return (lo[0] - margin, hi[0] + margin), (lo[1] - margin, hi[1] + margin)


def _elapsed(stamps: ArrayLike, t0: float | None) -> tuple[FloatArray, float]:
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    start = float(t[0]) if t0 is None and t.size else float(t0 or 0.0)
    return t - start, start


def _legend_above(ax: Axes, **kwargs: Any) -> None:
    """Legend in a row above the axes, where it cannot hide data points."""
    ax.legend(
        loc="lower left",
        bbox_to_anchor=(0.0, 1.0),
        ncol=2,
        frameon=False,
        fontsize="small",
        **kwargs,
    )


def _draw_active_view(
    ax: Axes, stamps: ArrayLike, view_ids: ArrayLike, new_mask: ArrayLike, t0: float | None
) -> None:
    t, _ = _elapsed(stamps, t0)
    ids = np.asarray(view_ids).reshape(-1)
    new = np.asarray(new_mask, dtype=bool).reshape(-1)
    if not (t.size == ids.size == new.size):
        raise ValueError(
            f"stamps, view_ids and new_mask differ in length: {t.size}, {ids.size}, {new.size}"
        )
    ax.scatter(t[new], ids[new], s=4, color=CONFIG.node_colour, label=f"new view ({new.sum()})")
    ax.scatter(
        t[~new], ids[~new], s=4, color=CONFIG.loop_colour, label=f"recognised view ({(~new).sum()})"
    )
    ax.set_ylabel("active view ID")
    _legend_above(ax, markerscale=3)
    ax.grid(True, lw=0.3, alpha=0.5)


def _draw_errors(
    ax: Axes,
    stamps: ArrayLike,
    errors: ArrayLike,
    odometry: tuple[ArrayLike, ArrayLike] | None,
    t0: float | None,
    gt_label: str = GROUND_TRUTH,
) -> None:
    t, start = _elapsed(stamps, t0)
    err = np.asarray(errors, dtype=np.float64).reshape(-1)
    if t.size != err.size:
        raise ValueError(f"stamps and errors differ in length: {t.size}, {err.size}")
    mean = float(np.nanmean(err)) if err.size else float("nan")
    ax.plot(t, err, color=CONFIG.node_colour, lw=1.0, label=f"bioslam (mean {mean:.3f} m)")
    if odometry is not None:
        odo_t, _ = _elapsed(odometry[0], start)
        odo_err = np.asarray(odometry[1], dtype=np.float64).reshape(-1)
        odo_mean = float(np.nanmean(odo_err)) if odo_err.size else float("nan")
        ax.plot(
            odo_t,
            odo_err,
            color=CONFIG.odometry_colour,
            lw=1.0,
            label=f"odometry only (mean {odo_mean:.3f} m)",
        )
    ax.set_ylabel("position error [m]" if gt_label == GROUND_TRUTH else f"error vs {gt_label} [m]")
    ax.set_ylim(bottom=0.0)
    _legend_above(ax)
    ax.grid(True, lw=0.3, alpha=0.5)


def _display_cells(prob: NDArray[np.float32], max_pixels: int) -> tuple[NDArray[np.float32], int]:
    """The map reduced by a whole factor to at most ``max_pixels`` a side, each pixel the
    highest probability of its block (a one-cell wall stays drawn; NaN only where the whole
    block is unknown), and that factor. matplotlib otherwise resamples the full map through
    several float64 and RGBA copies: ~200 MB for a 1900 x 1300-cell map, against the ~900
    pixels the figure has.
    """
    block = max(1, -(-max(prob.shape) // max_pixels))
    if block == 1:
        return prob, 1
    rows, cols = (-(-n // block) * block for n in prob.shape)
    padded = np.full((rows, cols), np.nan, dtype=np.float32)
    padded[: prob.shape[0], : prob.shape[1]] = prob
    blocks = padded.reshape(rows // block, block, cols // block, block)
    return np.fmax.reduce(np.fmax.reduce(blocks, axis=3), axis=1), block


# --- public figures ------------------------------------------------------------------------


def plot_cognitive_map(
    path: Target,
    nodes_xy: ArrayLike,
    links: Sequence[Link],
    gt_xy: ArrayLike | None = None,
    title: str = "Cognitive map",
    gt_label: str = GROUND_TRUTH,
) -> Target:
    """The cognitive map: experience nodes (Eq. 12), their links, loop links highlighted.

    ``nodes_xy`` (N, 2) experience positions; ``links`` ``(from, to, kind)`` node indices;
    ``gt_xy`` (M, 2) an optional ground-truth path drawn underneath, in the legend as
    ``gt_label`` (a log's corrected poses are a "reference", not the truth).
    """
    nodes = _xy(nodes_xy, "nodes_xy")
    fig = Figure(figsize=(CONFIG.panel_size * 1.4, CONFIG.panel_size * 1.2))
    ax = fig.add_subplot()
    _draw_map(ax, nodes, links, _xy(gt_xy, "gt_xy") if gt_xy is not None else None, gt_label)
    ax.set_title(title)
    ax.legend(loc="best", fontsize="small", markerscale=2)
    fig.tight_layout()
    return _save(fig, path, CONFIG.dpi)


def plot_active_view(
    path: Target,
    stamps: ArrayLike,
    view_ids: ArrayLike,
    new_mask: ArrayLike,
    t0: float | None = None,
) -> Target:
    """Active view ID over time (top of the paper's Fig. 6).

    ``new_mask`` marks scans whose view was new; the others re-recognised an older view (the
    off-diagonal points that mean loop closures). Times are shown from ``t0`` (default: first
    stamp).
    """
    fig = Figure(figsize=(8.0, 3.2))
    ax = fig.add_subplot()
    _draw_active_view(ax, stamps, view_ids, new_mask, t0)
    ax.set_xlabel("time [s]")
    fig.tight_layout()
    return _save(fig, path, CONFIG.dpi)


def plot_error_over_time(
    path: Target,
    stamps: ArrayLike,
    errors: ArrayLike,
    odometry_errors: tuple[ArrayLike, ArrayLike] | None = None,
    t0: float | None = None,
    gt_label: str = GROUND_TRUTH,
) -> Target:
    """Position error against ground truth (or the reference called ``gt_label``) over time
    (bottom of the paper's Fig. 6).

    ``odometry_errors`` is an optional ``(stamps, errors)`` of the odometry-only trajectory,
    drawn over the SLAM curve on the same time axis.
    """
    fig = Figure(figsize=(8.0, 3.2))
    ax = fig.add_subplot()
    _draw_errors(ax, stamps, errors, odometry_errors, t0, gt_label)
    ax.set_xlabel("time [s]")
    fig.tight_layout()
    return _save(fig, path, CONFIG.dpi)


def plot_views_and_errors(
    path: Target,
    stamps: ArrayLike,
    view_ids: ArrayLike,
    new_mask: ArrayLike,
    error_stamps: ArrayLike,
    errors: ArrayLike,
    odometry_errors: tuple[ArrayLike, ArrayLike] | None = None,
    gt_label: str = GROUND_TRUTH,
) -> Target:
    """The paper's Fig. 6 in one picture: active view ID above, position error below (against
    the ground truth or the reference called ``gt_label``), on a shared time axis starting at
    the first scan."""
    t0 = float(np.asarray(stamps, dtype=np.float64).reshape(-1)[0])
    fig = Figure(figsize=(8.0, 5.6))
    top, bottom = fig.subplots(2, 1, sharex=True)
    _draw_active_view(top, stamps, view_ids, new_mask, t0)
    _draw_errors(bottom, error_stamps, errors, odometry_errors, t0, gt_label)
    bottom.set_xlabel("time [s]")
    fig.tight_layout()
    return _save(fig, path, CONFIG.dpi)


def plot_mapping_progress(
    path: Target,
    snapshots: Sequence[tuple[float, ArrayLike, Sequence[Link]]],
    gt_xy: ArrayLike | None,
    gt_label: str = GROUND_TRUTH,
) -> Target:
    """The paper's Fig. 5: the cognitive map at several times beside the ground-truth path.

    ``snapshots`` ``[(t, nodes_xy, links), ...]`` with ``t`` in seconds since the start (one
    panel each, titled ``t = …``); a last panel shows ``gt_xy`` when given, titled
    ``gt_label``. All panels share the same axes limits so the growth of the map is comparable.
    """
    maps = [(float(t), _xy(nodes, f"nodes_xy at t = {t}"), links) for t, nodes, links in snapshots]
    truth = _xy(gt_xy, "gt_xy") if gt_xy is not None else None
    n_panels = len(maps) + (truth is not None)
    if n_panels == 0:
        raise ValueError("plot_mapping_progress needs at least one snapshot or a ground truth")
    fig = Figure(figsize=(CONFIG.panel_size * n_panels, CONFIG.panel_size + 0.4))
    axes = np.atleast_1d(fig.subplots(1, n_panels))
    for ax, (t, nodes, links) in zip(axes, maps, strict=False):
        _draw_map(ax, nodes, links)
        ax.set_title(f"t = {t:.0f} s ({len(nodes)} nodes)")
    if truth is not None:
        ax = axes[-1]
        ax.plot(*truth.T, color=CONFIG.truth_colour, lw=1.0)
        _finish_map_axes(ax)
        ax.set_title(gt_label)
    limits = _limits(*(nodes for _, nodes, _ in maps), *([truth] if truth is not None else []))
    if limits is not None:
        # Fixed, shared limits: the box (not the data range) gives way to keep metres square.
        for ax in axes:
            ax.set_aspect("equal", adjustable="box")
            ax.set_xlim(*limits[0])
            ax.set_ylim(*limits[1])
    fig.tight_layout()
    return _save(fig, path, CONFIG.dpi)


def plot_revisit_sharpness(
    path: Target,
    xy: ArrayLike,
    residuals: Sequence[tuple[str, ArrayLike]],
) -> Target:
    """Where a map agrees with itself (:mod:`bioslam.consistency`): one panel per trajectory,
    each judged scan at ``xy`` ((N, 2), the first trajectory's positions) coloured by its
    revisit residual (``residuals``: (name, (N,) metres) pairs; NaN not drawn), all on one
    logarithmic colour scale (millimetres where the scans agree, metres where they do not
    overlap or the trajectory is off), so that a place one trajectory leaves blurred shows
    against the others."""
    from matplotlib.colors import LogNorm

    points = _xy(xy, "xy")
    named = [(name, np.asarray(r, dtype=np.float64).reshape(-1) * 1e3) for name, r in residuals]
    if not named or any(r.size != len(points) for _, r in named):
        raise ValueError("need one residual per judged scan for every trajectory")
    finite = np.concatenate([r[np.isfinite(r) & (r > 0)] for _, r in named])
    low, high = np.percentile(finite, [5, 95]) if finite.size else (1.0, 10.0)
    norm = LogNorm(vmin=max(float(low), 0.1), vmax=max(float(high), float(low) * 10, 1.0))
    fig = Figure(figsize=(CONFIG.panel_size * len(named) + 1.2, CONFIG.panel_size),
                 layout="constrained")  # fmt: skip
    axes = np.atleast_1d(fig.subplots(1, len(named), sharex=True, sharey=True))
    drawn = None
    for ax, (name, r) in zip(axes, named, strict=True):
        keep = np.isfinite(r)
        drawn = ax.scatter(*points[keep].T, c=np.maximum(r[keep], norm.vmin), s=6,
                           cmap="viridis", norm=norm, lw=0)  # fmt: skip
        median = float(np.median(r[keep])) if keep.any() else float("nan")
        ax.set_title(f"{name}: median {median:.1f} mm", fontsize="small")
        _finish_map_axes(ax, adjustable="box")  # shared axes: the box gives way
    if drawn is not None:
        fig.colorbar(drawn, ax=list(axes), label="revisit residual [mm]", shrink=0.9)
    return _save(fig, path, CONFIG.dpi)


def plot_occupancy(
    path: Target,
    grid: OccupancyLike | tuple[ArrayLike, float, Sequence[float]],
    trajectory_xy: ArrayLike | None = None,
    gt_xy: ArrayLike | None = None,
) -> Target:
    """The occupancy map (black occupied, white free, grey unknown) with the trajectory.

    ``grid`` is a ``bioslam.io.mapfile.OccupancyImage`` or ``(probability, resolution,
    origin)`` with the same convention: row 0 is the lowest y, NaN is unknown, ``origin`` the
    (x, y[, yaw]) of the lower-left corner (a non-zero yaw is not drawn).
    """
    if hasattr(grid, "occupancy"):
        prob, resolution, origin = grid.occupancy, grid.resolution, grid.origin
    else:
        prob, resolution, origin = grid
    prob = np.asarray(prob, dtype=np.float32)
    if prob.ndim != 2 or prob.size == 0:
        raise ValueError(f"occupancy must be a non-empty 2-D array, got shape {prob.shape}")
    rows, cols = prob.shape
    shown, block = _display_cells(prob, CONFIG.max_map_pixels)
    x0, y0 = float(origin[0]), float(origin[1])
    cell = block * resolution
    extent = (x0, x0 + shown.shape[1] * cell, y0, y0 + shown.shape[0] * cell)
    aspect = rows / cols
    width = CONFIG.panel_size * 1.6
    fig = Figure(figsize=(width, max(3.0, min(width * aspect, 2.5 * width)) + 0.6))
    ax = fig.add_subplot()
    cmap = colormaps["gray"].with_extremes(bad=CONFIG.unknown_colour)
    # Resampled as one float32 value a cell and coloured after ("data" stage): an RGBA image,
    # or the default stage, makes matplotlib resample four float32 or float64 channels (a
    # 900 x 900-cell map drew in 47 MB as RGBA bytes, in 20 MB so; the same pixels, nearest).
    shade = np.ma.masked_invalid(1.0 - np.clip(shown, 0.0, 1.0), copy=False)
    ax.imshow(shade, cmap=cmap, vmin=0.0, vmax=1.0, origin="lower", extent=extent,
              interpolation="nearest", interpolation_stage="data")  # fmt: skip
    paths = [
        (gt_xy, "ground truth", CONFIG.truth_colour),
        (trajectory_xy, "trajectory", CONFIG.loop_colour),
    ]
    for xy, label, colour in paths:
        if xy is not None:
            ax.plot(*_xy(xy, label).T, color=colour, lw=0.9, label=label)
    if gt_xy is not None or trajectory_xy is not None:
        ax.legend(loc="best", fontsize="small")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"Occupancy map ({cols} x {rows} cells, {resolution:g} m)")
    fig.tight_layout()
    return _save(fig, path, CONFIG.dpi)
