"""Boundary-cell pictures: one scan's activity on its rings of receptive fields (the idea of
the paper's Fig. 2), drawn in the robot frame with the robot's heading pointing up."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from bioslam.boundary import BoundaryCellConfig


def plot_boundary_activity(
    path: str | Path,
    B: ArrayLike,
    config: BoundaryCellConfig,
    endpoints: ArrayLike | None = None,
    title: str = "",
    dpi: int = 120,
) -> Path:
    """Draw every cell as a wedge on its ring, coloured by its activity in ``B``; cells below
    1 % of the strongest are left blank.

    ``endpoints`` ``(N, 2)`` (sensor frame, metres) are overlaid as dots. Silent cells are left
    blank, so a limited field of view shows as an empty sector. Writes ``path`` (PNG).
    """
    b = np.asarray(B, dtype=np.float64)
    if b.shape != (config.num_cells,):
        raise ValueError(f"B has shape {b.shape}, the layout has {config.num_cells} cells")
    rings = np.asarray(config.ring_distances, dtype=np.float64)
    edges = _ring_edges(rings)
    n = config.cells_per_ring
    width = 2.0 * np.pi / n
    grid = b.reshape(rings.size, n)
    norm = Normalize(vmin=0.0, vmax=float(grid.max()) or 1.0)
    cmap = colormaps["viridis"]

    fig = Figure(figsize=(6.4, 6.0))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    # Gaussian tails make nearly every cell in reach non-zero; below 1 % of the peak a cell
    # is drawn as silent so the figure shows where the activity is.
    floor = 0.01 * float(grid.max())
    for r in range(rings.size):
        active = grid[r] > floor
        ax.bar(
            config.cell_angles()[active],
            edges[r + 1] - edges[r],
            width=width,
            bottom=edges[r],
            color=cmap(norm(grid[r, active])),
            edgecolor="none",
        )
    if endpoints is not None:
        pts = np.asarray(endpoints, dtype=np.float64).reshape(-1, 2)
        ax.scatter(np.arctan2(pts[:, 1], pts[:, 0]), np.hypot(pts[:, 0], pts[:, 1]), s=1.0,
                   color="red", label="scan endpoints")
        ax.legend(loc="lower left", fontsize="small")
    ax.set_ylim(0.0, edges[-1])
    ax.tick_params(labelsize="small")
    fig.colorbar(
        ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.7, label="boundary-cell activity"
    )
    ax.set_title(title or f"{rings.size} rings x {n} cells, heading up", fontsize="medium")
    FigureCanvasAgg(fig)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out


def _ring_edges(rings: np.ndarray) -> np.ndarray:
    """Radii between which each ring's wedges are drawn: half-way to the neighbouring rings."""
    first_gap = rings[1] - rings[0] if rings.size > 1 else rings[0]
    last_gap = rings[-1] - rings[-2] if rings.size > 1 else rings[0]
    inner = max(rings[0] - 0.5 * first_gap, 0.0)
    return np.concatenate([[inner], 0.5 * (rings[1:] + rings[:-1]), [rings[-1] + 0.5 * last_gap]])
