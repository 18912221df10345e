"""The run's figures drawn in a child process started with the command.

Importing matplotlib and drawing a run's figures take about a second of CPU once the last scan
is processed (on the 600 s simulated route: the import 0.4 s, the figures 0.6 s), in which
the command otherwise only waits. A :class:`FigureWorker` is forked when the command starts,
while its process is still small (what the child shares of it), and waits. The figures that
need no occupancy map are sent to it as soon as the trajectories are made: it imports
matplotlib and draws them while the parent writes the trajectories, the cognitive map and the
occupancy map, then draws the map's figure. Importing matplotlib only then keeps its 45 MB out
of the run's memory; it would gain about 0.1 s more if imported at the start.

It returns each figure as PNG bytes and the parent writes them: a worker stopped half-way
(a signal, a crash) leaves no file behind, and the output directory's record of its files
stays the parent's. A figure that fails comes back as its error, the others still drawn.
"""

from __future__ import annotations

import io
from typing import Any

from bioslam.io.forked import Channel, Forked, Helper

#: A figure to draw: its file name, the :mod:`bioslam.plots.figures` function that draws it
#: and that function's arguments after the path.
Job = tuple[str, str, tuple[Any, ...]]
#: A figure drawn: its file name and its PNG, or its error (``"Type: message"``).
Drawn = tuple[str, bytes | None, str | None]


class FigureWorker(Helper):
    """A child process that draws figures (module doc). Send it jobs with :meth:`draw` as
    their data is ready; :meth:`drawn` waits for all of them."""

    def __init__(self) -> None:
        self._child = Forked(_serve)

    def draw(self, jobs: list[Job]) -> None:
        """Queue ``jobs``; the child draws them in order as soon as it can."""
        self._child.send(jobs)

    def drawn(self) -> list[Drawn]:
        """Every figure queued since the last call, in order, once all are drawn."""
        self._child.send(None)
        result: list[Drawn] = self._child.receive()
        return result



def draw_png(job: Job) -> Drawn:
    """Draw one job into PNG bytes (or say why it failed)."""
    from bioslam.plots import figures

    name, plot, args = job
    try:
        buffer = io.BytesIO()
        getattr(figures, plot)(buffer, *args)
    except Exception as exc:  # reported with the figure; the others are still drawn
        return name, None, f"{type(exc).__name__}: {exc}"
    return name, buffer.getvalue(), None


def _serve(channel: Channel) -> None:
    """In the child: draw what comes until the parent leaves."""
    drawn: list[Drawn] = []
    while True:
        jobs = channel.receive()
        if jobs is None:
            channel.send(drawn)
            drawn = []
        else:
            drawn += [draw_png(job) for job in jobs]
