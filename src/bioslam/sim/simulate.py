"""Simulated LiDAR scans along a route: ray casting, the mirror sweep, noise, moving people."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import wrap_angle
from bioslam.scan import LaserScan
from bioslam.sim.lidar import LidarModel
from bioslam.sim.raycast import cast_rays
from bioslam.sim.route import Route
from bioslam.sim.world import World
from bioslam.trajectory import Trajectory

# Scans cast together: large enough to amortise the Python overhead, small enough to keep the
# (chunk x beams) buffers a few megabytes.
_CHUNK = 200


@dataclass(frozen=True)
class MovingObstacle:
    """A circle (a person: radius 0.25 m by default) walking back and forth between ``start``
    and ``end`` at ``speed`` m/s; at ``t = phase`` it is at ``start``."""

    start: tuple[float, float]
    end: tuple[float, float]
    speed: float = 1.0
    radius: float = 0.25
    phase: float = 0.0

    def __post_init__(self) -> None:
        if not self.radius > 0.0:
            raise ValueError(f"obstacle radius must be positive, got {self.radius}")
        if self.speed < 0.0:
            raise ValueError(f"obstacle speed must be >= 0, got {self.speed}")

    def position_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Centre ``(..., 2)`` at times ``t``."""
        a = np.asarray(self.start, dtype=np.float64)
        d = np.asarray(self.end, dtype=np.float64) - a
        length = float(np.hypot(*d))
        tt = np.asarray(t, dtype=np.float64)
        if length == 0.0 or self.speed == 0.0:
            return np.broadcast_to(a, (*tt.shape, 2)).copy()
        travelled = np.mod(self.speed * (tt - self.phase), 2.0 * length)
        frac = np.where(travelled <= length, travelled, 2.0 * length - travelled) / length
        return a + frac[..., None] * d


def people_on_roadmap(
    world: World,
    count: int,
    seed: int = 0,
    speed: float = 1.0,
    radius: float = 0.25,
    offset: float = 0.3,
) -> list[MovingObstacle]:
    """``count`` people pacing up and down roadmap edges (distinct ones while there are
    enough), each ``offset`` metres to the side of the centre-line so that a robot driving
    the centre-line passes them instead of going through them. 1 m/s is a slow walk."""
    road = world.roadmap
    if road is None or len(road.edges) == 0:
        raise ValueError(f"world {world.name!r} has no roadmap to place people on")
    rng = np.random.default_rng(seed)
    picks = rng.permutation(np.resize(np.arange(len(road.edges)), max(count, 0)))[:count]
    people = []
    for e in picks:
        a, b = road.nodes[road.edges[e]]
        side = (b - a)[::-1] * np.array([-1.0, 1.0]) / np.hypot(*(b - a))
        shift = side * offset * rng.choice([-1.0, 1.0])
        phase = float(rng.uniform(0.0, 2.0 * np.hypot(*(b - a)) / speed))
        people.append(
            MovingObstacle(tuple(a + shift), tuple(b + shift), speed, radius, phase)  # type: ignore[arg-type]
        )
    return people


def people_on_route(
    route: Route,
    spans: Sequence[tuple[float, float]] = ((0.15, 0.2), (0.45, 0.5), (0.75, 0.8)),
    speed: float = 1.2,
) -> list[MovingObstacle]:
    """People walking back and forth along stretches of the robot's own ``route``, one per
    span (fractions of its duration, start and end): they walk its centre-line, so the
    robot meets them head-on, follows them and passes close beside them."""
    d = route.duration
    return [
        MovingObstacle(tuple(route.pose_at(a * d)[:2]), tuple(route.pose_at(b * d)[:2]), speed)  # type: ignore[arg-type]
        for a, b in spans
    ]


def ray_circle_distance(
    origins: NDArray, angles: NDArray, centres: NDArray, radius: float
) -> NDArray[np.float64]:
    """Distance along each ray to a circle (``inf`` if missed, or if the ray starts inside)."""
    d = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    f = origins - centres
    b = np.einsum("...k,...k->...", f, d)
    c = np.einsum("...k,...k->...", f, f) - radius * radius
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    return np.where((disc >= 0.0) & (t >= 0.0) & (c > 0.0), t, np.inf)


def scan_stamps(lidar: LidarModel, route: Route, start: float = 0.0) -> NDArray[np.float64]:
    """Stamps of the scans a LiDAR takes along a route: every ``1 / rate_hz`` seconds from
    ``start``, while the whole scan still fits in the route."""
    sweep_span = lidar.time_increment * (lidar.beams - 1)
    n = int(np.floor((route.duration - sweep_span - start) * lidar.rate_hz + 1e-9)) + 1
    return start + np.arange(max(n, 0)) / lidar.rate_hz


def scanner_trajectory(lidar: LidarModel, route: Route, stamps: ArrayLike) -> Trajectory:
    """The scanner's ground truth at ``stamps``: the robot's poses turned by the LiDAR's
    ``mount_yaw`` (what a LiDAR-only SLAM run on its scans estimates)."""
    truth = route.trajectory(stamps)
    _turn_to_scanner(lidar, truth.poses)
    return truth


def _turn_to_scanner(lidar: LidarModel, poses: NDArray[np.float64]) -> None:
    """Turn the robot's ``poses`` (..., 3) in place into its scanner's (``mount_yaw``)."""
    if lidar.mount_yaw:
        poses[..., 2] = wrap_angle(poses[..., 2] + lidar.mount_yaw)


def true_ranges(
    world: World,
    lidar: LidarModel,
    route: Route,
    stamps: NDArray[np.float64],
    obstacles: Sequence[MovingObstacle] = (),
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact distances ``(len(stamps), beams)`` (``inf`` = nothing within ``range_max``) and
    the scanner's poses at the stamps. With the sweep on, beam ``k`` is cast from the pose at
    ``stamp + k * time_increment`` (the sensor sits at the robot's origin, turned by the
    LiDAR's ``mount_yaw`` from its forward axis)."""
    beam_times = stamps[:, None] + lidar.time_increment * np.arange(lidar.beams)
    poses = route.pose_at(beam_times)
    _turn_to_scanner(lidar, poses)
    angles = poses[..., 2] + lidar.angles()
    origins = poses[..., :2]
    ranges = cast_rays(world.grid, origins, angles, lidar.range_max)
    for obstacle in obstacles:
        centres = obstacle.position_at(beam_times)
        ranges = np.minimum(ranges, ray_circle_distance(origins, angles, centres, obstacle.radius))
    ranges[ranges > lidar.range_max] = np.inf
    return ranges, poses[:, 0, :]


def simulate_scans(
    world: World,
    lidar: LidarModel,
    route: Route,
    seed: int = 0,
    obstacles: Sequence[MovingObstacle] = (),
    start: float = 0.0,
) -> Iterator[tuple[LaserScan, NDArray[np.float64]]]:
    """Stream ``(scan, true_pose)`` along the route, one scan every ``1 / rate_hz`` seconds.

    ``scan.stamp`` is the time of its first beam and ``true_pose`` the scanner's pose then
    (the robot's, turned by the LiDAR's ``mount_yaw``);
    ranges are float32 with the sensor's noise and dropouts (REP 117 codes, see
    :mod:`bioslam.sim.lidar`). Deterministic for a given seed.
    """
    rng = np.random.default_rng(seed)
    stamps = scan_stamps(lidar, route, start)
    angles = lidar.angles()
    for lo in range(0, stamps.size, _CHUNK):
        chunk = stamps[lo : lo + _CHUNK]
        exact, poses = true_ranges(world, lidar, route, chunk, obstacles)
        measured = lidar.measure(exact, rng)
        for k, stamp in enumerate(chunk):
            scan = LaserScan(
                float(stamp),
                measured[k],
                angles,
                lidar.range_min,
                lidar.range_max,
                lidar.time_increment,
            )
            yield scan, poses[k]
