"""Routes that drive like a person with a joystick, not like a line follower: off the corridor
centre by up to half a metre and weaving, turning back halfway down a corridor to come back the
other way, stopping at corners to turn on the spot, then driving off fast.

Each of these is a case the odometry and the place recognition must survive on a real robot
(a view learned on the centre-line revisited 0.5 m to the side, at another heading, or from
the opposite direction; a spin that leaves the motion prior at zero while the robot speeds
off). The walk is the coverage walk of :mod:`bioslam.sim.route` with turn-backs and spins added;
between spins the path is rounded, offset sideways, smoothed and timed as there.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import minimum_filter1d

from bioslam.geometry import wrap_angle
from bioslam.sim.reversing import make_reversing_route
from bioslam.sim.route import (
    SHARPEST_ROUNDED,
    CoverageWalker,
    Route,
    RouteConfig,
    check_clearance,
    drop_straight_vertices,
    make_route,
    rounded_polyline,
    smoothed_path,
    timed_path,
    turn_angle,
)
from bioslam.sim.world import Roadmap, World

# Turns sharper than this are always taken on the spot: rounding them would need arcs the
# corridor has no room for (and a U-turn cannot be rounded at all).
_SHARPEST_ARC = 2.0
# Corners from this angle on may be taken on the spot (spin_prob); gentler bends are driven.
_CORNER = np.deg2rad(45.0)
# Sampling of spins on the spot, seconds.
_SPIN_DT = 0.005
# Waypoints closer than this (metres) are one: no stretch between spins is shorter.
_MIN_STEP = 0.05
# Extra distance kept from walls by the sideways offset, metres (room for the smoothing).
_OFFSET_MARGIN = 0.05


@dataclass(frozen=True)
class AdversarialConfig:
    """How hard the route is on a SLAM system.

    Attributes:
        route: the driving limits (speed, yaw rate, acceleration, clearance, arcs), as for
            :func:`bioslam.sim.make_route`; 1 rad/s and 1 m/s^2 by default, a brisk driver.
        lateral_offset: largest sideways offset from the roadmap's centre-lines, metres; the
            offset weaves from side to side, each swing between half and all of it, and is cut
            where the corridor has no room for it (the clearance is always kept).
        swing: range of distances between the extremes of the weave, metres.
        turn_back_every: mean distance between turn-backs, metres: on an edge of length L the
            robot stops part way with probability ``1 - exp(-L / turn_back_every)``, turns on
            the spot and drives back (the place revisited the other way). Per metre, so that
            roadmaps of short edges (map_server lattices) and of long aisles are alike.
        spin_prob: chance that a corner of 45 degrees or more is taken by stopping and turning
            on the spot instead of on an arc.
        spin_rate: fastest turn on the spot, rad/s; ``spin_accel`` its angular acceleration.
        fast_speed: speed limit of a stretch after a spin, m/s, for half of those stretches
            (chosen at random); the others keep ``route.max_speed``.
    """

    route: RouteConfig = field(
        default_factory=lambda: RouteConfig(max_yaw_rate=1.0, max_accel=1.0)
    )
    lateral_offset: float = 0.5
    swing: tuple[float, float] = (3.0, 8.0)
    turn_back_every: float = 40.0
    spin_prob: float = 0.3
    spin_rate: float = 1.5
    spin_accel: float = 3.0
    fast_speed: float = 1.2

    def __post_init__(self) -> None:
        if self.lateral_offset < 0.0:
            raise ValueError(f"lateral offset must be >= 0, got {self.lateral_offset}")
        if not 0.0 < self.swing[0] <= self.swing[1]:
            raise ValueError(f"swing must be a range of positive distances, got {self.swing}")
        if not 0.0 <= self.spin_prob <= 1.0:
            raise ValueError(f"spin_prob must be in [0, 1], got {self.spin_prob}")
        for name in ("turn_back_every", "spin_rate", "spin_accel", "fast_speed"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass
class _Waypoints:
    """The walk as points to drive through; ``stop[i]`` = halt at point ``i`` and turn on the
    spot there; ``tour`` = the roadmap nodes reached, in order."""

    points: list[NDArray] = field(default_factory=list)
    stop: list[bool] = field(default_factory=list)
    tour: list[int] = field(default_factory=list)

    def add(self, point: NDArray, stop: bool = False) -> None:
        self.points.append(np.asarray(point, dtype=np.float64))
        self.stop.append(stop)


def adversarial_walk(
    roadmap: Roadmap, rng: np.random.Generator, min_length: float, cfg: AdversarialConfig
) -> _Waypoints:
    """The coverage walk (every corridor, then again, both ways) with turn-backs part way
    along edges and corners taken on the spot, at least ``min_length`` metres long."""
    walker = CoverageWalker(roadmap, rng, max_turn=1.75)
    nodes = roadmap.nodes
    cur, prev, length = walker.start(), -1, 0.0
    way = _Waypoints(tour=[cur])
    way.add(nodes[cur])
    while length < min_length:
        nxt = walker.choose(prev, cur)
        if prev >= 0 and prev != cur:
            turn = turn_angle(nodes, prev, cur, nxt)
            sharp = turn > _SHARPEST_ARC or (turn > _CORNER and rng.random() < cfg.spin_prob)
            way.stop[-1] = way.stop[-1] or sharp
        edge = float(np.hypot(*(nodes[nxt] - nodes[cur])))
        if rng.random() < -np.expm1(-edge / cfg.turn_back_every):
            f = rng.uniform(0.4, 1.0)
            way.add(nodes[cur] + f * (nodes[nxt] - nodes[cur]), stop=True)
            way.add(nodes[cur])
            length += 2.0 * f * edge
            prev = nxt  # back where it came from: now it may leave by any other exit
            continue
        length += walker.drive(cur, nxt)
        way.add(nodes[nxt])
        way.tour.append(nxt)
        prev, cur = cur, nxt
    return way


def _cosine_knots(s: NDArray, knots: NDArray, values: NDArray) -> NDArray:
    """Smooth (C1) interpolation through ``(knots, values)``: half a cosine between knots."""
    i = np.clip(np.searchsorted(knots, s, side="right") - 1, 0, len(knots) - 2)
    u = np.clip((s - knots[i]) / (knots[i + 1] - knots[i]), 0.0, 1.0)
    w = 0.5 - 0.5 * np.cos(np.pi * u)
    return values[i] * (1.0 - w) + values[i + 1] * w


def lateral_offsets(
    world: World, path: NDArray, cfg: AdversarialConfig, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Sideways offsets (left positive, metres) for the samples of ``path``: a weave through
    alternating extremes, zero at both ends (where the robot turns on the spot), cut to what
    keeps the route's clearance and stays inside the bend of a curve."""
    step = np.hypot(*np.diff(path, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(step)])
    total = float(s[-1])
    if total < cfg.swing[0]:
        return np.zeros(len(path))  # too short a stretch to weave
    gaps = rng.uniform(*cfg.swing, size=int(total / cfg.swing[0]) + 2)
    knots = np.concatenate([[0.0], np.cumsum(gaps)])
    knots = knots[knots < total - 0.5 * cfg.swing[0]]
    sizes = cfg.lateral_offset * rng.uniform(0.5, 1.0, size=len(knots))
    sides = rng.choice([-1.0, 1.0]) * (-1.0) ** np.arange(len(knots))
    values = np.concatenate([sizes * sides, [0.0]])
    values[0] = 0.0
    wanted = _cosine_knots(s, np.concatenate([knots, [total]]), values)
    # Room: the wall distance of the centre-line bounds that of any point within d of it.
    coarse = slice(None, None, 10)
    room = np.interp(s, s[coarse], minimum_filter1d(world.distance_to_walls(path[coarse]), 3))
    room = room - cfg.route.clearance - _OFFSET_MARGIN
    # Inside a bend the offset must stay well short of the bend's radius (else the path loops).
    grad = np.gradient(path, s, axis=0)
    curvature = np.gradient(np.unwrap(np.arctan2(grad[:, 1], grad[:, 0])), s)
    inward = np.sign(wanted) == np.sign(curvature)
    inner = np.where(inward, 0.5 / np.maximum(np.abs(curvature), 1e-9), np.inf)
    window = 2 * int(0.5 / cfg.route.step) + 1
    limit = minimum_filter1d(np.maximum(np.minimum(room, inner), 0.0), window)
    return np.clip(wanted, -limit, limit)


def _offset_path(path: NDArray, offsets: NDArray) -> NDArray:
    step = np.hypot(*np.diff(path, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(step)])
    grad = np.gradient(path, s, axis=0)
    grad /= np.hypot(*grad.T)[:, None]
    return path + offsets[:, None] * np.column_stack([-grad[:, 1], grad[:, 0]])


def _pinned(xy: NDArray, start: NDArray, end: NDArray) -> NDArray:
    """``xy`` bent (linearly along its length) so that it starts and ends exactly at the
    given points: the smoothing moves a path's ends by millimetres, a spin must not."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    w = (s / s[-1])[:, None]
    return xy + (start - xy[0]) * (1.0 - w) + (end - xy[-1]) * w


def _spin(heading: float, delta: float, cfg: AdversarialConfig) -> tuple[NDArray, NDArray]:
    """Times (from 0, excluded) and headings of a turn on the spot by ``delta`` radians:
    accelerate, turn at ``spin_rate``, brake (a triangle profile when the turn is short)."""
    a, w = cfg.spin_accel, cfg.spin_rate
    angle = abs(delta)
    ramp = min(w / a, np.sqrt(angle / a))
    peak = a * ramp
    cruise = max(angle - a * ramp * ramp, 0.0) / peak
    total = 2.0 * ramp + cruise
    t = np.linspace(0.0, total, max(int(np.ceil(total / _SPIN_DT)), 2) + 1)[1:]
    up = 0.5 * a * np.minimum(t, ramp) ** 2
    mid = peak * np.clip(t - ramp, 0.0, cruise)
    down_t = np.clip(t - ramp - cruise, 0.0, ramp)
    down = peak * down_t - 0.5 * a * down_t**2
    turned = np.minimum(up + mid + down, angle)
    return t, heading + np.sign(delta) * turned


def _legs(way: _Waypoints) -> list[NDArray]:
    """The waypoints cut at every stop; points within ``_MIN_STEP`` of the previous one are
    merged into it (a stop there happens at the previous point). A merge can leave a turn
    sharper than any arc rounds (:data:`bioslam.sim.route.SHARPEST_ROUNDED`) where the walk
    had two gentler ones (a roadmap edge of a few centimetres between two corners of a map's
    corridor: the ring floor plan's route of seed 155 went back the way it came there): it is
    cut there too, a turn on the spot."""
    legs, current = [], [way.points[0]]
    for point, stop in zip(way.points[1:], way.stop[1:], strict=True):
        if np.hypot(*(point - current[-1])) > _MIN_STEP:
            if len(current) > 1 and _turn(current[-2], current[-1], point) > SHARPEST_ROUNDED:
                legs.append(np.array(current))
                current = [current[-1]]
            current.append(point)
        if stop and len(current) > 1:
            legs.append(np.array(current))
            current = [current[-1]]
    if len(current) > 1:
        legs.append(np.array(current))
    return legs


def _turn(a: NDArray, b: NDArray, c: NDArray) -> float:
    """The absolute heading change at ``b`` on the way ``a -> b -> c``, radians."""
    return turn_angle(np.array([a, b, c]), 0, 1, 2)


def _drive_leg(
    world: World, points: NDArray, cfg: RouteConfig, adv: AdversarialConfig,
    rng: np.random.Generator,
) -> tuple[NDArray, NDArray]:
    """Times and poses of one stretch between spins, from rest to rest."""
    slack = world.distance_to_walls(points) - cfg.clearance - cfg.corner_margin
    points, slack = drop_straight_vertices(points, slack)
    dense = rounded_polyline(points, slack, cfg.effective_turn_radius, cfg.step)
    dense = dense[np.concatenate([[True], np.hypot(*np.diff(dense, axis=0).T) > 1e-9])]
    if adv.lateral_offset > 0.0 and len(dense) > 2:
        dense = _offset_path(dense, lateral_offsets(world, dense, adv, rng))
    xy = smoothed_path(dense, cfg)
    if len(xy) < 2:
        xy = dense[[0, -1]]
    xy = _pinned(xy, points[0], points[-1])
    times, poses, _ = timed_path(xy, cfg, stop_at_end=True)
    return times, poses


def make_adversarial_route(
    world: World,
    duration: float = 600.0,
    seed: int = 0,
    config: AdversarialConfig | None = None,
) -> Route:
    """A route of ``duration`` seconds through ``world`` that is hard on SLAM (see the
    module): off-centre and weaving, turning back part way, spinning on the spot at corners
    and speeding off. Deterministic for a given world, duration, seed and config. Raises
    ``ValueError`` when the world has no roadmap or the clearance cannot be kept."""
    if not duration > 0.0:
        raise ValueError(f"route duration must be positive, got {duration}")
    adv = config or AdversarialConfig()
    roadmap = world.roadmap
    if roadmap is None:
        raise ValueError(f"world {world.name!r} has no roadmap to build a route on")
    rng = np.random.default_rng(seed)
    fastest = max(adv.route.max_speed, adv.fast_speed)
    way = adversarial_walk(roadmap, rng, 1.2 * duration * fastest + 5.0, adv)
    times, poses = [np.zeros(1)], [np.array([[*way.points[0], 0.0]])]
    elapsed, heading = 0.0, None
    for k, leg in enumerate(_legs(way)):
        fast = k > 0 and rng.random() < 0.5
        cfg = replace(adv.route, max_speed=adv.fast_speed) if fast else adv.route
        t, p = _drive_leg(world, leg, cfg, adv, rng)
        if heading is None:
            poses[0][0, 2] = heading = float(p[0, 2])
        else:
            delta = float(wrap_angle(p[0, 2] - heading))
            if abs(delta) > np.pi - 0.05 and rng.random() < 0.5:  # a half turn: either way
                delta -= float(np.copysign(2.0 * np.pi, delta))
            if abs(delta) > 1e-6:
                st, sh = _spin(heading, delta, adv)
                times.append(elapsed + st)
                poses.append(np.column_stack([np.tile(p[0, :2], (len(st), 1)), sh]))
                elapsed += float(st[-1])
            # Continue the unwrapped heading (the leg's own differs by whole turns).
            p[:, 2] += heading + delta - p[0, 2]
        times.append(elapsed + t[1:])
        poses.append(p[1:])
        elapsed += float(t[-1])
        heading = float(p[-1, 2])
        if elapsed > duration:
            break
    all_t, all_p = np.concatenate(times), np.vstack(poses)
    if all_t[-1] < duration:
        raise ValueError(f"route too short: {all_t[-1]:.1f} s of {duration:.1f} s")
    cut = int(np.searchsorted(all_t, duration)) + 1
    all_t, all_p = all_t[: cut + 1], all_p[: cut + 1]
    check_clearance(world, all_p, adv.route.clearance)
    return Route(all_t, all_p, float(duration), np.asarray(way.tour, dtype=np.int64))


#: Route generators by name (``bioslam sim --route``): each takes ``(world, duration, seed,
#: config)``.
ROUTES = {
    "tour": make_route,
    "adversarial": make_adversarial_route,
    "reversing": make_reversing_route,
}
