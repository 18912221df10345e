"""A tour that backs up: now and then the robot reverses along its own path (ours).

Robots back out of dead ends and doorways; a thinned log then holds steps a metre *behind* the
robot, which a matcher that assumes forward motion takes for look-alikes. This route is the
seeded tour of :func:`bioslam.sim.route.make_route` with, every ``every`` seconds of driving,
``back`` seconds of that same stretch driven in reverse (heading unchanged, the path retraced)
and then forward again, so that it never leaves the clearance the tour kept.
"""

from __future__ import annotations

import numpy as np

from bioslam.sim.route import Route, RouteConfig, make_route
from bioslam.sim.world import World


def make_reversing_route(
    world: World,
    duration: float = 600.0,
    seed: int = 0,
    config: RouteConfig | None = None,
    every: float = 45.0,
    back: float = 12.0,
    sample: float = 0.05,
) -> Route:
    """A route of ``duration`` seconds: the tour, reversed for ``back`` seconds after every
    ``every`` seconds of forward driving (then driven forward again over the same stretch).
    ``sample``: the spacing in time of the poses the route is made of (seconds)."""
    if not (every > back > 0.0 and sample > 0.0):
        raise ValueError(
            f"need every > back > 0 and sample > 0, got {every}, {back}, {sample}"
        )
    # a cycle of every + back seconds advances the tour by every - back seconds: a tour of
    # ``duration`` seconds outlasts the route
    tour = make_route(world, duration=duration, seed=seed, config=config)
    clock = _tour_clock(tour.duration, duration, every, back, sample)
    poses = tour.pose_at(clock)
    poses[:, 2] = np.unwrap(poses[:, 2])
    return Route(np.arange(clock.size) * sample, poses)


def _tour_clock(
    tour_duration: float, duration: float, every: float, back: float, sample: float
) -> np.ndarray:
    """The tour's times the route passes through, ``sample`` seconds apart: forward for
    ``every``, back for ``back`` (the same times, descending), forward again, until the
    route lasts ``duration`` (or the tour ends)."""
    need = int(np.ceil(duration / sample)) + 1
    pieces: list[np.ndarray] = []
    total, start = 0, 0.0
    while total < need and start < tour_duration:
        end = min(start + every, tour_duration)
        turn = max(end - back, 0.0)
        for piece in (np.arange(start, end, sample), np.arange(end, turn, -sample)):
            pieces.append(piece)
            total += piece.size
        start = turn if end < tour_duration else tour_duration
    return np.concatenate(pieces)[:need]
