"""Robot routes through a world: a seeded tour of the roadmap, smoothed and timed.

The tour walks the roadmap preferring the directed edges driven least often, so it covers every
corridor, then drives them again, in the other direction too: loops get closed both ways. The
corners of the tour are rounded with circular arcs no wider than the clearance at the corner
allows, the path is lightly low-pass filtered so that curvature (and with it the yaw rate) has
no jumps, and the speed along it is the fastest profile within the speed, yaw-rate and
acceleration limits. Deterministic for a given world, duration and seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from bioslam.geometry import wrap_angle
from bioslam.sim.world import Roadmap, World
from bioslam.trajectory import Trajectory


@dataclass(frozen=True)
class RouteConfig:
    """Limits and shape of a route.

    Attributes:
        max_speed: m/s; 0.5 is the issue's limit (an indoor robot driven by hand).
        max_yaw_rate: rad/s; 0.8 is a careful driver's cornering rate (ours).
        max_accel: m/s^2, for speeding up and braking; 0.5 is typical of small indoor robots.
        clearance: the route never gets closer than this to a wall, metres (the issue: 0.3).
        turn_radius: radius of the arcs that round corners, metres, reduced where the corner
            is too tight; 0.6 m is about half a corridor.
        fast_turns: odometry stress test: corners taken on 0.25 m arcs at 1 rad/s.
        smoothing: standard deviation of the low-pass filter along the path, metres; 0.1 m
            makes the curvature continuous while moving the path by a few centimetres.
        step: spacing of the path samples, metres.
        corner_margin: extra distance kept from walls when sizing corner arcs, metres (room
            for the smoothing).
    """

    max_speed: float = 0.5
    max_yaw_rate: float = 0.8
    max_accel: float = 0.5
    clearance: float = 0.3
    turn_radius: float = 0.6
    fast_turns: bool = False
    smoothing: float = 0.1
    step: float = 0.01
    corner_margin: float = 0.1

    def __post_init__(self) -> None:
        for name in ("max_speed", "max_yaw_rate", "max_accel", "turn_radius", "step"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"route {name} must be positive, got {getattr(self, name)}")
        if self.clearance < 0.0:
            raise ValueError(f"route clearance must be >= 0, got {self.clearance}")

    @property
    def effective_yaw_rate(self) -> float:
        return 1.0 if self.fast_turns else self.max_yaw_rate

    @property
    def effective_turn_radius(self) -> float:
        return 0.25 if self.fast_turns else self.turn_radius


@njit(cache=True)
def _interpolate(times, poses, speeds, t, out):  # pragma: no cover - numba
    """Poses at times ``t`` between samples: at constant acceleration when ``speeds`` is given
    (so velocity is continuous, even from rest), else at constant velocity. The simulator asks
    for every beam of every scan, so this is a hot loop."""
    last = times.shape[0] - 2
    for n in range(t.shape[0]):
        i = min(max(np.searchsorted(times, t[n], side="right") - 1, 0), last)
        dt = times[i + 1] - times[i]
        tau = t[n] - times[i]
        if speeds.shape[0] == 0:
            f = tau / dt
        else:
            v0 = speeds[i]
            v1 = speeds[i + 1]
            f = (v0 * tau + 0.5 * (v1 - v0) / dt * tau * tau) / (0.5 * (v0 + v1) * dt)
        f = min(max(f, 0.0), 1.0)
        for k in range(3):
            out[n, k] = poses[i, k] * (1.0 - f) + poses[i + 1, k] * f


@dataclass(frozen=True, eq=False)
class Route:
    """A timed path: ``times`` (M,) from 0, ``poses`` (M, 3) with unwrapped heading, and
    optionally the ``speeds`` (M,) there, m/s.

    With ``speeds``, the robot moves between samples at constant acceleration (so its velocity
    is continuous, also from rest); without, at constant velocity. ``tour`` lists the roadmap
    nodes visited, in order. ``duration`` defaults to the last time. Hand-made routes (a robot
    spinning on the spot, say) need only ``times`` and ``poses``.
    """

    times: NDArray[np.float64]
    poses: NDArray[np.float64]
    duration: float | None = None
    tour: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    speeds: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        times = np.ascontiguousarray(self.times, dtype=np.float64).reshape(-1)
        poses = np.ascontiguousarray(self.poses, dtype=np.float64)
        if times.size < 2 or poses.shape != (times.size, 3):
            raise ValueError(
                f"a route needs >= 2 times and one (x, y, theta) per time, got {times.shape} "
                f"times and poses {poses.shape}"
            )
        if not np.all(np.diff(times) > 0.0):
            raise ValueError("route times must be strictly increasing")
        if self.speeds is not None:
            speeds = np.ascontiguousarray(self.speeds, dtype=np.float64)
            if speeds.shape != times.shape:
                raise ValueError(f"route speeds {speeds.shape} do not match times {times.shape}")
            object.__setattr__(self, "speeds", speeds)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "poses", poses)
        duration = float(times[-1]) if self.duration is None else float(self.duration)
        object.__setattr__(self, "duration", duration)

    def pose_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Poses ``(..., 3)`` at times ``t`` (seconds, clamped to ``[0, duration]``)."""
        tt = np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration)
        flat = np.ascontiguousarray(tt.reshape(-1))
        out = np.empty((flat.size, 3))
        speeds = np.zeros(0) if self.speeds is None else self.speeds
        _interpolate(self.times, self.poses, speeds, flat, out)
        out[:, 2] = wrap_angle(out[:, 2])
        return out.reshape(*tt.shape, 3)

    def trajectory(self, stamps: ArrayLike) -> Trajectory:
        """Ground truth at the given stamps."""
        stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
        return Trajectory(stamps, self.pose_at(stamps))

    def path_length(self) -> float:
        """Distance driven within ``[0, duration]``, metres."""
        keep = self.times <= self.duration
        return float(np.sum(np.hypot(*np.diff(self.poses[keep, :2], axis=0).T)))


def turn_angle(nodes: NDArray, a: int, b: int, c: int) -> float:
    """Absolute heading change at ``b`` on the way ``a -> b -> c``, radians."""
    u, v = nodes[b] - nodes[a], nodes[c] - nodes[b]
    return abs(float(np.arctan2(u[0] * v[1] - u[1] * v[0], u @ v)))


#: A turn sharper than this (radians) doubles back: :func:`rounded_polyline` cannot round it.
U_TURN = math.radians(170.0)
#: ... and sharper than this it refuses to (an arc's tangent length grows without bound).
SHARPEST_ROUNDED = math.radians(178.0)


class CoverageWalker:
    """Chooses exits on a roadmap the way a coverage walk does: the exit driven least often in
    that direction (ties broken at random), avoiding turns sharper than ``max_turn`` radians
    where it can, never turning back unless a node is a dead end."""

    def __init__(self, roadmap: Roadmap, rng: np.random.Generator, max_turn: float) -> None:
        self.nodes = roadmap.nodes
        self.adj = roadmap.neighbours()
        if not any(self.adj):
            raise ValueError("the world's roadmap has no edges to drive along")
        self.rng = rng
        self.max_turn = max_turn
        self.driven: dict[tuple[int, int], int] = {}

    def start(self) -> int:
        return int(self.rng.choice([i for i, a in enumerate(self.adj) if a]))

    def choose(self, prev: int, cur: int) -> int:
        """The next node after driving ``prev -> cur`` (``prev`` < 0 at the start). A node
        whose exits all turn sharper than ``max_turn`` takes the least driven of them, but
        never one that doubles back (:data:`U_TURN`) while another is left: on a map's
        roadmap two neighbours can lie in nearly the same direction (nodes sit where the
        free space of their block is), and the way on to the second from the first is then a
        U-turn that no arc can round (a floor plan's route raised at seed 3)."""
        options = [n for n in self.adj[cur] if n != prev] or self.adj[cur]
        turns = {n: turn_angle(self.nodes, prev, cur, n) if prev >= 0 else 0.0 for n in options}
        options = [n for n in options if turns[n] <= U_TURN] or options
        keys = [
            (
                turns[n] > self.max_turn,
                self.driven.get((cur, n), 0),
                self.driven.get((n, cur), 0),
                # Straight on first among equals: a driver does not zig-zag down a corridor.
                turns[n] > 0.2,
                self.rng.random(),
            )
            for n in options
        ]
        return options[min(range(len(options)), key=keys.__getitem__)]

    def drive(self, cur: int, nxt: int) -> float:
        """Count the edge as driven; its length, metres."""
        self.driven[(cur, nxt)] = self.driven.get((cur, nxt), 0) + 1
        return float(np.hypot(*(self.nodes[nxt] - self.nodes[cur])))


def coverage_walk(
    roadmap: Roadmap, rng: np.random.Generator, min_length: float, max_turn: float = 1.75
) -> list[int]:
    """A walk over the roadmap of at least ``min_length`` metres that always takes the exit
    driven least often in that direction (ties broken at random), avoiding turns sharper than
    ``max_turn`` radians (100 degrees) where it can, never turning back unless a node is a
    dead end."""
    walker = CoverageWalker(roadmap, rng, max_turn)
    tour, prev, length = [walker.start()], -1, 0.0
    while length < min_length:
        cur = tour[-1]
        nxt = walker.choose(prev, cur)
        length += walker.drive(cur, nxt)
        prev = cur
        tour.append(nxt)
    return tour


def drop_straight_vertices(points: NDArray, slack: NDArray) -> tuple[NDArray, NDArray]:
    """The polyline without its vertices where it goes straight on (nothing to round there),
    with the matching ``slack``; turn-backs are kept."""
    d = np.diff(points, axis=0)
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    dot = np.einsum("ij,ij->i", d[:-1], d[1:])
    keep = np.ones(len(points), dtype=bool)
    keep[1:-1] = (np.abs(cross) > 1e-9 * np.hypot(*d[:-1].T) * np.hypot(*d[1:].T)) | (dot < 0)
    return points[keep], slack[keep]


def _line(p: NDArray, q: NDArray, step: float) -> NDArray:
    n = max(int(np.ceil(np.hypot(*(q - p)) / step)), 1)
    return p + (q - p) * (np.arange(n)[:, None] / n)


def rounded_polyline(points: NDArray, slack: NDArray, radius: float, step: float) -> NDArray:
    """Dense samples of the polyline with each corner replaced by a tangent circular arc whose
    radius is ``radius`` at most, small enough that neighbouring arcs do not overlap and that
    the arc stays within ``slack[i]`` of corner ``i``."""
    pieces = []
    cursor = points[0]
    for i in range(1, len(points) - 1):
        a, p, b = points[i - 1], points[i], points[i + 1]
        u, v = p - a, b - p
        lu, lv = np.hypot(*u), np.hypot(*v)
        u, v = u / lu, v / lv
        phi = float(np.arctan2(u[0] * v[1] - u[1] * v[0], u @ v))
        if abs(phi) > SHARPEST_ROUNDED:
            raise ValueError(f"the route turns back at {p.tolist()}: cannot round a U-turn")
        half = 0.5 * abs(phi)
        r = min(
            radius,
            0.5 * min(lu, lv) / np.tan(half),
            max(slack[i], 0.0) / (1.0 / np.cos(half) - 1.0),
        )
        tangent = r * np.tan(half)
        start, end = p - u * tangent, p + v * tangent
        pieces.append(_line(cursor, start, step))
        normal = np.array([-u[1], u[0]]) * np.sign(phi)
        centre = start + normal * r
        a0 = np.arctan2(*(start - centre)[::-1])
        n = max(int(np.ceil(r * abs(phi) / step)), 1)
        ang = a0 + phi * np.arange(n) / n
        pieces.append(centre + r * np.column_stack([np.cos(ang), np.sin(ang)]))
        cursor = end
    pieces.append(_line(cursor, points[-1], step))
    pieces.append(points[-1][None])
    return np.vstack(pieces)


def _speed_profile(
    s: NDArray, heading: NDArray, cfg: RouteConfig, stop_at_end: bool = False
) -> NDArray:
    """Fastest speeds at the path samples under the speed, yaw-rate and acceleration limits,
    starting from rest (and coming to rest at the end with ``stop_at_end``)."""
    ds = np.diff(s)
    # Curvature of each interval between samples; a sample's speed must respect both of its
    # intervals so that the heading change per interval, over its duration, stays in limits.
    bend = np.abs(np.diff(heading)) / ds
    bend = np.maximum(np.concatenate([bend[:1], bend]), np.concatenate([bend, bend[-1:]]))
    with np.errstate(divide="ignore"):
        v = np.minimum(cfg.max_speed, cfg.effective_yaw_rate / bend)
    v[0] = 0.0
    if stop_at_end:
        v[-1] = 0.0
    two_a = 2.0 * cfg.max_accel
    for i in range(1, len(v)):
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + two_a * ds[i - 1]))
    for i in range(len(v) - 2, 0, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + two_a * ds[i]))
    return v


def smoothed_path(dense: NDArray, cfg: RouteConfig) -> NDArray:
    """The path low-pass filtered (continuous curvature), repeated samples dropped."""
    from scipy.ndimage import gaussian_filter1d  # SciPy only when a route is planned

    xy = gaussian_filter1d(dense, cfg.smoothing / cfg.step, axis=0, mode="nearest")
    seg = np.hypot(*np.diff(xy, axis=0).T)
    keep = np.concatenate([[True], seg > 1e-9])
    return xy[keep]


def timed_path(
    xy: NDArray, cfg: RouteConfig, stop_at_end: bool = False
) -> tuple[NDArray, NDArray, NDArray]:
    """Times, poses (heading along the path, unwrapped) and speeds of the fastest drive along
    the samples ``xy`` from rest."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    grad = np.gradient(xy, s, axis=0)
    heading = np.unwrap(np.arctan2(grad[:, 1], grad[:, 0]))
    v = _speed_profile(s, heading, cfg, stop_at_end)
    dt = 2.0 * np.diff(s) / (v[1:] + v[:-1])
    times = np.concatenate([[0.0], np.cumsum(dt)])
    return times, np.column_stack([xy, heading]), v


def _smoothed_timed_path(dense: NDArray, cfg: RouteConfig) -> tuple[NDArray, NDArray, NDArray]:
    return timed_path(smoothed_path(dense, cfg), cfg)


def check_clearance(world: World, poses: NDArray, clearance: float) -> None:
    """Raise ``ValueError`` when a route comes closer than ``clearance`` to a wall."""
    nearest = float(world.distance_to_walls(poses[:, :2]).min())
    if nearest < clearance:
        raise ValueError(
            f"route in world {world.name!r} comes {nearest:.3f} m from a wall "
            f"(clearance {clearance} m); the roadmap is too close to the walls"
        )


def make_route(
    world: World,
    duration: float = 600.0,
    seed: int = 0,
    max_speed: float | None = None,
    max_yaw_rate: float | None = None,
    clearance: float | None = None,
    fast_turns: bool | None = None,
    config: RouteConfig | None = None,
) -> Route:
    """A smooth route of ``duration`` seconds that explores ``world`` and revisits it.

    Keyword limits given (not ``None``) override the matching fields of ``config``, whose
    defaults are those of :class:`RouteConfig` (0.5 m/s, 0.8 rad/s, 0.3 m clearance). Raises
    ``ValueError`` when the world has no roadmap or the route would come closer than the
    clearance to a wall.
    """
    if not duration > 0.0:
        raise ValueError(f"route duration must be positive, got {duration}")
    overrides = {
        "max_speed": max_speed,
        "max_yaw_rate": max_yaw_rate,
        "clearance": clearance,
        "fast_turns": fast_turns,
    }
    cfg = replace(config or RouteConfig(), **{k: v for k, v in overrides.items() if v is not None})
    roadmap = world.roadmap
    if roadmap is None:
        raise ValueError(f"world {world.name!r} has no roadmap to build a route on")
    rng = np.random.default_rng(seed)
    # Driving is never faster than max_speed, so duration * max_speed metres of driving last
    # long enough; the margin pays for the length that rounding the corners cuts off.
    tour = coverage_walk(roadmap, rng, 1.2 * duration * cfg.max_speed + 5.0)
    points = roadmap.nodes[tour]
    slack = roadmap.clearance[tour] - cfg.clearance - cfg.corner_margin
    points, slack = drop_straight_vertices(points, slack)
    dense = rounded_polyline(points, slack, cfg.effective_turn_radius, cfg.step)
    times, poses, speeds = _smoothed_timed_path(dense, cfg)
    if times[-1] < duration:
        raise ValueError(f"route too short: {times[-1]:.1f} s of {duration:.1f} s")
    cut = int(np.searchsorted(times, duration)) + 1
    times, poses, speeds = times[: cut + 1], poses[: cut + 1], speeds[: cut + 1]
    check_clearance(world, poses, cfg.clearance)
    return Route(times, poses, float(duration), np.asarray(tour, dtype=np.int64), speeds)
