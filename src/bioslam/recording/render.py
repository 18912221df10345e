"""A picture of a recording, drawn from the MCAP file's own messages (not a screenshot): the
last occupancy map (``/map``) with the last cognitive map (``/cognitive_map``) on top, the way
the 3D panel shows them, and what each is made of in the title.

    python -m bioslam.recording.render RUN.mcap OUT.png
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bioslam.recording import topics as tp
from bioslam.recording.reading import last_message


def grid_image(grid: Any) -> tuple[NDArray[np.uint8], tuple[float, float, float, float]]:
    """A decoded ``foxglove.Grid`` of RGBA cells as an ``(rows, cols, 4)`` image (row 0 at the
    lowest y) and its extent ``(xmin, xmax, ymin, ymax)`` in its frame (the pose's rotation is
    taken to be none, as the recorder writes it)."""
    names = [f.name for f in grid.fields]
    if names[:4] != ["red", "green", "blue", "alpha"] or grid.cell_stride != 4:
        raise ValueError(f"grid fields {names} (stride {grid.cell_stride}) are not RGBA cells")
    cols = grid.column_count
    data = np.frombuffer(grid.data, dtype=np.uint8)
    rows = len(data) // grid.row_stride
    image = data[: rows * grid.row_stride].reshape(rows, grid.row_stride)[:, : 4 * cols]
    image = image.reshape(rows, cols, 4)
    x0, y0 = grid.pose.position.x, grid.pose.position.y
    extent = (x0, x0 + cols * grid.cell_size.x, y0, y0 + rows * grid.cell_size.y)
    return image, extent


def _known_bounds(
    image: NDArray[np.uint8], extent: tuple[float, float, float, float], margin: float = 0.5
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The x and y limits of the observed (opaque) cells plus a margin; the whole grid when
    nothing was observed."""
    rows, cols = np.nonzero(image[..., 3])
    if rows.size == 0:
        return (extent[0], extent[1]), (extent[2], extent[3])
    cell_x = (extent[1] - extent[0]) / image.shape[1]
    cell_y = (extent[3] - extent[2]) / image.shape[0]
    return (
        (extent[0] + cols.min() * cell_x - margin, extent[0] + (cols.max() + 1) * cell_x + margin),
        (extent[2] + rows.min() * cell_y - margin, extent[2] + (rows.max() + 1) * cell_y + margin),
    )


def _rgba(colour: Any) -> tuple[float, float, float, float]:
    return (colour.r, colour.g, colour.b, colour.a)


def scene_geometry(scene: Any) -> dict[str, Any]:
    """Spheres (positions, sizes, colours) and line lists / strips (segments, colour) of a
    decoded ``foxglove.SceneUpdate``."""
    spheres, lines = [], []
    for entity in scene.entities:
        for s in entity.spheres:
            spheres.append((s.pose.position.x, s.pose.position.y, s.size.x, _rgba(s.color)))
        for line in entity.lines:
            xy = np.array([(p.x, p.y) for p in line.points]).reshape(-1, 2)
            if line.type == 2:  # LINE_LIST: pairs of points
                segments = xy.reshape(-1, 2, 2)
            else:  # LINE_STRIP
                segments = np.stack([xy[:-1], xy[1:]], axis=1) if len(xy) > 1 else xy[:0]
            lines.append((segments.reshape(-1, 2, 2), _rgba(line.color), line.thickness))
    return {"spheres": spheres, "lines": lines}


def render(mcap_path: str | Path, png_path: str | Path, dpi: int = 130) -> dict[str, int]:
    """Draw the last map and cognitive map of a recording; return what was drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    grid = last_message(mcap_path, tp.MAP)
    scene = last_message(mcap_path, tp.COGNITIVE_MAP)
    if grid is None:
        raise ValueError(f"{mcap_path}: no {tp.MAP} message to draw")
    image, extent = grid_image(grid)
    fig, ax = plt.subplots(figsize=(8, 6.4))
    ax.set_facecolor("#c8c8c8")  # unknown cells are transparent
    ax.imshow(image, origin="lower", extent=extent, interpolation="nearest")
    drawn = {"grid_cells": int(image.shape[0] * image.shape[1]), "experiences": 0, "links": 0}
    if scene is not None:
        geometry = scene_geometry(scene)
        for segments, colour, thickness in geometry["lines"]:
            if len(segments):
                ax.add_collection(LineCollection(segments, colors=[colour],
                                                 linewidths=0.5 * max(thickness, 1.0)))
                drawn["links"] += len(segments)
        if geometry["spheres"]:
            x, y, size, colour = zip(*geometry["spheres"], strict=True)
            ax.scatter(x, y, s=8 * (np.array(size) / min(size)) ** 2, c=list(colour),
                       linewidths=0, zorder=3)
            drawn["experiences"] = len(x)
    xlim, ylim = _known_bounds(image, extent)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, map frame)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{Path(mcap_path).name}: {tp.MAP} and {tp.COGNITIVE_MAP} (last messages)",
                 fontsize=10)
    fig.tight_layout()
    Path(png_path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=dpi)
    plt.close(fig)
    return drawn


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Draw a recording's map and cognitive map.")
    parser.add_argument("mcap", type=Path)
    parser.add_argument("png", type=Path)
    args = parser.parse_args(argv)
    print(render(args.mcap, args.png))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
