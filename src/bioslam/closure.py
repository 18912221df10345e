"""Loop-closure candidates and their verification against local submaps (Sec. III-C).

The paper closes a loop when a view cell fires for a place the pose cells agree with. Two
things make that fragile on real robots, and this module is where they are handled:

* **Candidates from two cues.** A boundary view is recognised only within a limited offset of
  where it was learned, while a hand-driven robot returns half a metre off. As an animal's
  path integration says "I am near where I was", the map proposes the nearest experience
  within the odometry's drift bound of the robot's map pose (:func:`nearest_experience`),
  beside the view cells' own candidate. Experiences the robot has just left, or that a short
  chain of links already joins to the current one, are not loops and are not proposed.
  Where a check to a place was refused as ambiguous, the cue goes back to that place first
  (:func:`first_marked_experience`): the map, which made the area anew, would otherwise
  propose only the new copy.
* **Verification that look-alikes cannot fool.** A candidate is accepted only after the
  current scan is registered against a *submap* fused from the scans of the experiences
  around the candidate on its own pass (:func:`fuse_submap`): one scan sees a corridor's
  walls but not its end, several scans a metre apart see the doors that tell it from its
  twin. The registration must fit (score), be constrained in every direction (not
  degenerate), stay within what the odometry can have drifted, and be unambiguous (no
  distinct rival pose nearly as good, when the matcher reports one). One that leaves only a
  slide along a corridor free may stand as a *partial* closure: what it pins, across the
  corridor and the heading, under the same tests (:func:`sliding`).

No I/O here; :class:`bioslam.slam.BioSLAM` calls these once per look.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from bioslam.cognitive_map import registration_shape
from bioslam.config import LoopClosureConfig
from bioslam.geometry import (
    between,
    compose,
    inverse,
    rotation,
    transform_points,
    unit,
    wrap_angle,
)
from bioslam.matching.branch_and_bound import (
    WideBasinConfig,
    WideBasinMatcher,
    WideMatch,
    refine,
)
from bioslam.matching.gauss_newton import MatchReport, levels_up_to
from bioslam.matching.point_to_line import LineFit, LineMap, refine_point_to_line
from bioslam.matching.registration import RegistrationConfig, densify_scan
from bioslam.occupancy_grid import (
    NORMAL_MAX_GAP,
    NORMAL_RADIUS,
    LogOddsConfig,
    MapPyramid,
    OccupancyGrid,
    scan_normals,
)

FloatArray = NDArray[np.float64]

#: Fewest judged points a registration's weak modes are taken from (:func:`judged_shape`).
MIN_JUDGED = 20


def thin_points(points: FloatArray, spacing: float) -> NDArray[np.float32]:
    """Keep one point per ``spacing``-sized grid cell: a compact scan to store with a place."""
    if points.shape[0] == 0 or spacing <= 0.0:
        return points.astype(np.float32)
    cells = np.floor(points / spacing).astype(np.int64)
    # One integer key per cell (a 1-D unique is far cheaper than a row-wise one).
    keys = (cells[:, 0] << 32) + (cells[:, 1] & 0xFFFFFFFF)
    _, first = np.unique(keys, return_index=True)
    return points[np.sort(first)].astype(np.float32)


def pass_neighbours(
    travelled: FloatArray, anchor: int, reach: float, step: float, before: float
) -> list[int]:
    """The experiences whose scans make ``anchor``'s submap: on its own pass (ids are in
    creation order, ``travelled`` the odometry distance at which each was made,
    non-decreasing), the one nearest each multiple of ``step`` metres of travel within
    ``reach`` of it, made no later than ``before`` metres of travel; ``anchor`` always."""
    centre = travelled[anchor]
    k = int(reach // step) if step > 0 else 0
    targets = centre + step * np.arange(-k, k + 1)
    targets = targets[targets <= before]
    picks = np.clip(np.searchsorted(travelled, targets), 0, travelled.size - 1)
    near = [int(i) for i in picks if abs(travelled[i] - centre) <= reach and travelled[i] <= before]
    return sorted({anchor, *near})


def odometry_broke(
    report: MatchReport,
    step: FloatArray,
    expected: FloatArray,
    dt: float,
    config: LoopClosureConfig,
    max_speed: float = math.inf,
    last: FloatArray | None = None,
) -> bool:
    """Whether the odometry's last ``step`` (robot frame) breaks its chain of relative poses:
    no match was made (the step is a guess), or a search replaced the match from the motion
    model, or kept it among look-alikes, and the step departs from the motion ``expected``
    over its ``dt`` seconds (the last step's velocity) by more than a robot can have changed
    its motion in that time (``break_distance`` / ``break_angle`` plus half the
    ``break_acceleration`` / ``break_angular_acceleration`` times dt²): a jump to another
    pose, right or to a look-alike. After a gap in the scans a robot may have done anything,
    and a search that finds where it went is no break (freiburg-079: 26 such recoveries,
    none 0.6 m from the motion after gaps of up to 2.3 s). Between consecutive scans of the
    simulated maze the odometry jumped 0.5 m along corridors (SICK) and 1.9 m (URG-04LX),
    and closures then confirmed the jump. A step along a direction the scan does not
    constrain (``report.degenerate``) faster than ``max_speed`` (m/s) is a break too, and
    so is a step the odometry reports it cannot vouch for (``report.broken``), one after which
    it rebuilt its map, in conflict with the scans (``report.rebuilt``), or one that
    turns away from the motion kept only by the map's veto of a better match turned the
    other way (``report.vetoed``: a thinned SICK spinning in a ring corridor's office took
    a 120° turn for a true -60° the map rejected, and turned back 180° two seconds later;
    closures to the place made between the two then confirmed it, 1.5-2.4 m and 180° off).
    ``last``: the step before as it was; given, a searched step must depart from it too
    (:func:`jumped`): where a log's stamps jitter or repeat, the motion scaled by the interval
    overshoots or falls short of a steady step (freiburg-079 jittered by 0.2 s: 147 breaks)."""
    if report.predicted_only or report.broken or report.rebuilt:
        return True  # no match, or one the odometry itself cannot vouch for
    if report.vetoed and _departure(step, expected)[1] > config.break_angle:
        # the veto kept a turn the motion does not bear out (kept with the motion, as by a
        # 10 Hz scanner spinning on the spot between look-alike matches, it is no break)
        return True
    if report.degenerate and math.hypot(step[0], step[1]) > max_speed * dt:
        # blind along a corridor, the odometry ran faster than the robot can move (URG-04LX
        # maze: 2.9 m/s backwards while the robot drove on at 0.5 m/s)
        return True
    if not (report.recovered or report.ambiguous):
        return False  # the match from the motion model's own start, kept: no jump
    if last is not None:
        return jumped(step, last, expected, dt, config)
    return implausible(step, expected, dt, config)


def turned_after_break(
    report: MatchReport,
    step: FloatArray,
    expected: FloatArray,
    scans_since: float,
    config: LoopClosureConfig,
    break_turn: float,
) -> bool:
    """Whether ``step``, a search's step ``scans_since`` scans after a break (at most
    ``break_echo``), turns away from the ``expected`` motion by more than ``break_turn``
    (the odometry's): the odometry turning back into a frame it left at the break (a thinned
    URG-04LX spinning in a symmetric office turned 154° at a break, and 136° for a true -45°
    three scans later, the match fitting the map it had left; a closure to the place made
    in between was 1.2 m and 179° off)."""
    if scans_since > config.break_echo or not report.recovered:
        return False
    return _departure(step, expected)[1] > break_turn


def implausible(
    step: FloatArray, expected: FloatArray, dt: float, config: LoopClosureConfig
) -> bool:
    """Whether ``step`` departs from the ``expected`` motion by more than a robot can change
    its motion in ``dt`` seconds (:func:`break_thresholds`), however the odometry matched
    it: on the simulated rooms the odometry, tracking without a search, slid 20 cm back in
    one scan and forward again seconds later."""
    (moved, turned), (max_moved, max_turned) = (
        _departure(step, expected),
        break_thresholds(dt, config),
    )
    return moved > max_moved or turned > max_turned


def jumped(
    step: FloatArray, last: FloatArray, expected: FloatArray, dt: float, config: LoopClosureConfig
) -> bool:
    """Whether ``step`` is :func:`implausible` both against the ``expected`` motion (the
    ``last`` step's velocity over this step's ``dt``) and against the ``last`` step as it
    was: where the stamps jitter (freiburg-079: a scan 0.05-0.1 s after the one before, the
    next 0.24 s after it) the scaled expectation overshoots a steady motion; a slide or a
    jump departs from both."""
    return implausible(step, expected, dt, config) and implausible(step, last, dt, config)


class SlideReturns:
    """The odometry's slides that it undid. A scan-to-map odometry that slides away from
    the robot's motion (a one-scan jump of 20 cm along a corridor) often jumps back a few
    scans later, when its map pulls it there: the steps between are displaced, but the
    motion across the pair is as good as any. Fed each jump's departure from the robot's
    motion (map frame), it says when a run of jumps has summed back to within
    ``thresholds`` (m, rad) of none, within ``reach`` metres of travel of the first."""

    def __init__(self, thresholds: tuple[float, float], reach: float) -> None:
        self.thresholds = thresholds
        self.reach = reach
        self._net: FloatArray | None = None
        self._since = 0.0

    @property
    def open(self) -> bool:
        """Whether a slide is under way (the odometry's pose now displaced by it) as of the
        last :meth:`travel` or :meth:`jump`."""
        return self._net is not None

    def travel(self, travelled: float) -> None:
        """The odometry has travelled ``travelled`` metres: a slide not undone within
        ``reach`` of its start is forgotten now, not at the next jump. (Held open until
        then, every place made for hundreds of metres counted as displaced by it, and its
        start was the one a later slide's return was bridged from: simulated ring floor,
        a 360° scanner of 3.5 m, a link of 223 m of odometry that the map took as exact.)"""
        if self._net is not None and travelled - self._since > self.reach:
            self._net = None  # never undone: the jumps stay as they are

    def jump(self, departure: ArrayLike, travelled: float) -> str:
        """Take one jump's ``departure`` (x, y, θ in the odometry's frame) after
        ``travelled`` metres: ``'opened'`` when it starts a slide, ``'returned'`` when it
        undid the open one, else ``''`` (the slide goes on)."""
        d = np.asarray(departure, dtype=np.float64).reshape(3)
        self.travel(travelled)
        if self._net is None:
            self._net, self._since = d.copy(), travelled
            return "opened"
        self._net += d
        self._net[2] = wrap_angle(float(self._net[2]))
        if within(self._net, *self.thresholds):
            self._net = None
            return "returned"
        return ""


class BreakRun:
    """Breaks of the odometry in a row after gaps or on a thinned log's steps, and how far
    (m) together they moved its position from where the robot's speed before them (the last
    step before the run) would have, each step along the odometry's own heading: a break's
    own departure from the step before counts a jump twice, once for the jump and once for
    the step that resumes the motion after it (simulated library, a 3.5 m scanner kept every
    third scan: a sideways jump of 0.78 m that put the odometry back on the truth, and the
    next step, departed 0.78 and 0.72 m), and a stall between two jumps not at all
    (cubicles: jumps of 1.36 and 1.54 m back with a stalled step between put the odometry
    4.0 m off, one cubicle's pitch). Headings are not compared: over a thinned log's steps a
    robot may turn anyhow (the break thresholds allow 113° in 0.6 s), and the steady turn
    carried on through a run counts the robot's own turns."""

    def __init__(self, steady: FloatArray, steady_dt: float) -> None:
        self._steady = np.asarray(steady, dtype=np.float64).reshape(3)
        self._steady_dt = steady_dt
        self._offset = np.zeros(2)
        self._heading = 0.0
        #: how far (m) the run has moved the odometry from the steady motion so far
        self.moved = 0.0

    def step(self, dp: FloatArray, dt: float) -> float:
        """Take the run's next step ``dp`` (robot frame) ``dt`` seconds after the last: how
        far (m) the run has now moved the odometry from the steady motion."""
        steady = motion_over(self._steady, self._steady_dt, dt)
        dx, dy = dp[0] - steady[0], dp[1] - steady[1]
        c, s = math.cos(self._heading), math.sin(self._heading)
        self._offset += (c * dx - s * dy, s * dx + c * dy)
        self._heading += float(dp[2])
        self.moved = math.hypot(self._offset[0], self._offset[1])
        return self.moved


def break_extent(
    step: FloatArray, expected: FloatArray, dt: float, config: LoopClosureConfig
) -> FloatArray:
    """How far (m, rad) a step that broke the odometry's chain (:func:`odometry_broke`) may
    have put the robot from where it went: its departure from the ``expected`` motion, at
    least what a robot could have changed its motion by in ``dt`` (a step without a match,
    or one blind along a corridor, has no departure of its own to tell)."""
    return np.maximum(np.array(_departure(step, expected)), np.array(break_thresholds(dt, config)))


def break_departure(
    step: FloatArray, expected: FloatArray, last: FloatArray
) -> tuple[float, float]:
    """How far (m, rad) a step that broke the odometry's chain departed from the robot's
    motion: from the ``expected`` motion (the last step's velocity over this step's
    interval) or from the ``last`` step as it was, whichever is nearer, each component on
    its own. Unlike :func:`break_extent` it has no floor from the time since the last scan:
    a jump to a look-alike departs from both, a true step after a gap of seconds in a
    thinned log from neither by much (intel: 33 m of extent after 5.8 s for a step 6 cm
    from the reference's)."""
    (far, turned), (far_last, turned_last) = _departure(step, expected), _departure(step, last)
    return min(far, far_last), min(turned, turned_last)


def link_extent(extent: FloatArray, config: LoopClosureConfig) -> FloatArray:
    """A break's ``extent`` (m, rad; :func:`break_extent`) as the map's link that carries it
    is weakened by: at most the window a loop closure's verification searches
    (``search_distance``, ``search_angle``), the largest error a closure can measure. After
    a gap of seconds the break thresholds grow to anything (10 s: 500 rad), and a link that
    uncertain is a free hinge: the closures across it turn the stretches between hinges at
    will (intel, with the odometry's stretches held by the learned link noise: ATE 9.6 ->
    12.2 cm, capped 9.6 as with the configured noise)."""
    return np.minimum(extent, (config.search_distance, config.search_angle))


def odometry_doubted(report: MatchReport) -> bool:
    """Whether the odometry's matcher itself doubted a step: no match was made, the scan
    left some direction unconstrained (blind along a corridor, where it may slide), or a
    distinct pose fitted about as well. A closure to a place the odometry relates to the
    robot only across such a step may confirm the step's error instead of the place (the
    simulated worlds' false closures, 0.56-1.48 m off, all came after such steps), so it
    needs another closure to agree (:class:`ClosureConsensus`); across steps it never
    doubted, one verified registration is enough (freiburg-079: none doubted)."""
    return bool(report.predicted_only or report.degenerate or report.ambiguous)


# (m, rad) pairs as plain floats: both run twice at every scan (:func:`jumped`), where
# two-element arrays cost more than the comparison.
def _departure(step: FloatArray, expected: FloatArray) -> tuple[float, float]:
    """How far (m, rad) ``step`` lands from the ``expected`` motion."""
    return (
        math.hypot(step[0] - expected[0], step[1] - expected[1]),
        abs(float(wrap_angle(float(step[2] - expected[2])))),
    )


def motion_over(step: FloatArray, step_dt: float, dt: float) -> FloatArray:
    """``step``, taken in ``step_dt`` seconds, carried on at its speed for ``dt`` seconds
    (at most a thousand such steps: a stamp repeated in a log leaves ``step_dt`` near zero);
    none when ``step_dt`` is none."""
    if step_dt <= 0.0:
        return np.zeros(3)
    return step * min(dt / step_dt, 1e3)


def break_thresholds(dt: float, config: LoopClosureConfig) -> tuple[float, float]:
    """The most (m, rad) a robot's motion can change in ``dt`` seconds: ``break_distance``
    / ``break_angle`` plus half the break accelerations times dt²."""
    slack = 0.5 * dt * dt
    return (
        config.break_distance + config.break_acceleration * slack,
        config.break_angle + config.break_angular_acceleration * slack,
    )


def submap_span(
    travelled: FloatArray, anchor: int, reach: float, step: float, max_reach: float
) -> tuple[float, float]:
    """The reach and step (m of travel) of ``anchor``'s submap (:func:`pass_neighbours`):
    ``reach`` and ``step`` where the pass made experiences at least every ``step`` metres;
    where it made them sparser (a log thinned to a scan a metre, where consecutive scans
    often keep one view: 2.3 m between experiences on freiburg-079), the step becomes their
    spacing and the reach grows by as much, up to ``max_reach``, so that the submap fuses
    about as many scans. From one or two scans a submap is too narrow: correct
    registrations there scored 0.75-0.89 and were refused."""
    lo, hi = max(anchor - 2, 0), min(anchor + 2, travelled.size - 1)
    if hi <= lo or max_reach <= reach:
        return reach, step
    spacing = float(travelled[hi] - travelled[lo]) / (hi - lo)
    if spacing <= step or step <= 0:
        return reach, step
    return max(reach, min(reach * spacing / step, max_reach)), spacing


def unbroken(jumps_at: NDArray[np.int64], anchor: int, members: Sequence[int]) -> list[int]:
    """The ``members`` of ``anchor``'s submap made with no break of the odometry, nor any other
    step no robot can make, between them and the anchor (``jumps_at``: the count of such
    steps when each experience was made)."""
    return [m for m in members if jumps_at[m] == jumps_at[anchor]]


def submap_anchor(travelled: FloatArray, anchor: int, step: float) -> int:
    """The experience whose submap verifies a candidate ``anchor``: on the same pass, the one
    made nearest the multiple of ``step`` metres of travel nearest ``anchor``'s. Checks a
    fraction of a step apart at one old place then share a submap (:class:`SubmapCache`)
    instead of each fusing its own around its own candidate."""
    if step <= 0:
        return anchor
    target = round(travelled[anchor] / step) * step
    i = int(np.searchsorted(travelled, target))
    picks = [j for j in (i - 1, i) if 0 <= j < travelled.size]
    best = min(picks, key=lambda j: abs(travelled[j] - target))
    return best if abs(travelled[best] - travelled[anchor]) <= step else anchor


def fuse_submap(
    poses: FloatArray,
    payloads: Sequence[FloatArray | None],
    anchor: int,
    members: Sequence[int],
    spacing: float,
) -> NDArray[np.float32]:
    """The scans stored with ``members`` fused into ``anchor``'s frame, thinned to one point
    per ``spacing`` cell. Members of one pass are related by the odometry over a few metres,
    so their relative map poses are good to the odometry's local accuracy."""
    parts = []
    for m in members:
        scan = payloads[m]
        if scan is None or len(scan) == 0:
            continue
        rel = between(poses[anchor], poses[m])
        parts.append(transform_points(rel, np.asarray(scan, dtype=np.float64)))
    if not parts:
        return np.zeros((0, 2), dtype=np.float32)
    return thin_points(np.concatenate(parts), spacing)


class SeenArea:
    """The cells the beams of a submap's member scans crossed or ended in, and those a wall's
    thickness behind each endpoint, in the anchor's frame: where the submap can vouch for
    what is there.

    Off the centre-line or turned, the robot sees walls, room corners and doorways the old
    pass never saw; a point of the current scan there is neither a hit nor a miss, since the
    submap knows nothing of that place. Points in cells the old pass saw free still count
    as misses, so a wrong alignment (points in open space) still fails. So do points just
    behind a wall it saw: a thin wall seen from the other side (a room's wall from the
    corridor) must not let a pose that puts the far faces onto the near ones score (it did
    by 19 cm in the identical-rooms test). Cells beside a beam that grazed a wall are not
    counted: the old pass saw little of that wall, the robot turned towards it sees it all.
    Each wall cell, the cells a wall's thickness behind it and those beside them keep the
    normals of the walls seen there, turned towards the scanners that saw them
    (``facing``), so that a point on a face the old pass saw only from its other side is
    told apart (:meth:`faces_away`)."""

    #: metres behind each endpoint, along its beam, that count as seen (a wall's thickness)
    BEHIND = 0.3

    def __init__(
        self,
        poses: FloatArray,
        payloads: Sequence[FloatArray | None],
        anchor: int,
        members: Sequence[int],
        resolution: float,
    ) -> None:
        scans = []
        for m in members:
            scan = payloads[m]
            if scan is not None and len(scan):
                rel = between(poses[anchor], poses[m])
                # a ray per cell width along the scan is enough to mark the cells it crosses
                pts = thin_points(np.asarray(scan, dtype=np.float64), 0.5 * resolution)
                scans.append((rel, pts.astype(np.float64)))
        self.resolution = float(resolution)
        if not scans:
            self.origin = np.zeros(2)
            self.mask = np.zeros((1, 1), dtype=bool)
            self.facing = np.zeros((1, 1, 2), dtype=np.float32)
            return
        # the endpoint itself, then a wall's thickness behind it
        offsets = np.arange(0, math.ceil(self.BEHIND / resolution) + 1) * resolution
        behind, towards = [], []
        for rel, pts in scans:
            ranges = np.maximum(np.hypot(pts[:, 0], pts[:, 1]), 1e-9)[None, :, None]
            beyond = pts[None, :, :] * (1.0 + offsets[:, None, None] / ranges)
            behind.append(transform_points(rel, beyond.reshape(-1, 2)))
            # the walls' normals, towards the sensor that saw them (zero where none)
            normal = scan_normals(np.ascontiguousarray(pts), NORMAL_RADIUS, NORMAL_MAX_GAP)
            back = normal @ rotation(float(rel[2])).T
            towards.append(np.broadcast_to(back, (offsets.size, *back.shape)).reshape(-1, 2))
        corners = np.concatenate([*behind, *(rel[None, :2] for rel, _ in scans)])
        lo, hi = corners.min(axis=0) - resolution, corners.max(axis=0) + resolution
        grid = OccupancyGrid.from_extent(resolution, (*lo, *hi), subcell=False)
        for rel, pts in scans:
            grid.insert_scan(rel, pts)
        self.origin = grid.origin
        self.mask = grid.known_mask()
        cells, ok = self._cells(np.concatenate(behind))
        facing = np.zeros((*self.mask.shape, 2))
        _mark_walls(self.mask, facing, cells[ok], np.concatenate(towards)[ok])
        self.facing = facing.astype(np.float32)

    def _cells(self, world: FloatArray) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        cells = np.floor((world - self.origin) / self.resolution).astype(np.int64)
        rows, cols = self.mask.shape
        ok = (cells[:, 0] >= 0) & (cells[:, 0] < cols) & (cells[:, 1] >= 0) & (cells[:, 1] < rows)
        return cells, ok

    def covers(self, world: FloatArray) -> NDArray[np.bool_]:
        """Whether each anchor-frame point lies in a seen cell."""
        cells, ok = self._cells(world)
        out = np.zeros(world.shape[0], dtype=bool)
        out[ok] = self.mask[cells[ok, 1], cells[ok, 0]]
        return out

    def judges_scan(self, pose: FloatArray, points: FloatArray) -> NDArray[np.bool_]:
        """:meth:`judges` for a scan's sensor-frame ``points`` taken at ``pose`` (the
        anchor's frame)."""
        return self.judges(transform_points(pose, points), pose)

    def judges(self, world: FloatArray, sensor: FloatArray) -> NDArray[np.bool_]:
        """Whether each anchor-frame point, seen from ``sensor``, is one the submap can judge:
        where its scans looked (:meth:`covers`) and not on a far face (:meth:`faces_away`)."""
        return self.covers(world) & ~self.faces_away(world, sensor)

    def faces_away(self, world: FloatArray, sensor: FloatArray) -> NDArray[np.bool_]:
        """Whether each anchor-frame point, seen from ``sensor`` (x, y), lies on a wall (or a
        wall's thickness behind one) that the submap's scans saw only from its other side.
        Such a point is the wall's far face, which the submap never saw: a partition a few
        centimetres thick falls in one cell with its near face, and a pose that put the
        current scan's far-face points onto the near face fitted best (identical cubicles,
        180° scanner, a pass the other way: closures 7-12 cm and 1° off at scores
        0.90-0.97, the truth scoring 0.5-0.8)."""
        cells, ok = self._cells(world)
        out = np.zeros(world.shape[0], dtype=bool)
        facing = self.facing[cells[ok, 1], cells[ok, 0]]
        looking = np.asarray(sensor, dtype=np.float64)[:2] - world[ok]
        out[ok] = np.einsum("ij,ij->i", facing, looking) < 0.0
        return out


#: where a check without a submap's seen area looked: nowhere (:func:`seen_hit_fraction`)
_NOWHERE = SeenArea(np.zeros((1, 3)), [None], 0, [], 1.0)


@njit(cache=True)
def _mark_walls(mask, facing, cells, towards):
    """:class:`SeenArea`'s wall cells (``cells``: column, row; each endpoint and the cells
    a wall's thickness behind it) marked seen in ``mask``, and each one's direction back to
    the scanner that saw it (``towards``) added to ``facing`` there and in the cells beside
    it: a wall's face the submap never saw lies within a cell of the one it saw, where a
    beam grazing along it may have crossed a cell as free."""
    rows, cols = mask.shape
    for k in range(cells.shape[0]):
        col, row = cells[k, 0], cells[k, 1]
        mask[row, col] = True
        for r in range(max(row - 1, 0), min(row + 2, rows)):
            for c in range(max(col - 1, 0), min(col + 2, cols)):
                facing[r, c, 0] += towards[k, 0]
                facing[r, c, 1] += towards[k, 1]


@dataclass
class Submap:
    """What verifies candidates near one old place, in the frame of experience ``anchor``:
    the member scans fused (``points``), where they looked (``seen``), the map pyramid the
    registration runs on, and the members' poses relative to the anchor when it was built
    (``layout``)."""

    anchor: int
    members: tuple[int, ...]
    layout: FloatArray
    points: NDArray[np.float32]
    seen: SeenArea
    pyramid: MapPyramid | None = field(default=None, repr=False)
    _lines: LineMap | None = field(default=None, repr=False)

    def lines(self) -> LineMap:
        """The fused points as lines (:mod:`bioslam.matching.point_to_line`), built when
        first asked for: only accepted checks are polished on them (:func:`polish_on_lines`)."""
        if self._lines is None:
            self._lines = LineMap.build(self.points)
        return self._lines


class SubmapCache:
    """The last ``size`` submaps built, reused while their members keep their relative poses
    (to ``tolerance`` metres / radians: the map's relaxation may bend a pass, and a submap
    fused along the old bend would not fit the new one). At most ``max_bytes`` are kept
    (each submap's registration pyramid is a few megabytes: 2.3 MB on the simulated maze),
    the most recently used first; a submap rebuilt is the same, so the limits change only
    the time. The reuse is of the last few (checks a fraction of a submap step apart at one
    place): 8 MB gave the same hits as 24 MB (86 of 392 checks on the 600 s simulated maze,
    68 of 360 on freiburg-079; 67 with 6 MB).

    One more submap may be built ahead of its check (:meth:`prefetch`), on a scan that runs
    none, with the lines an accepted check is polished on: fusing a submap is a third of a
    check's cost (5-6 ms of 15-20 on the simulated warehouse and maze), and most checks go to
    a place whose submap no check has built yet.
    The check adopts it only if its members still lie exactly where they did, so that it
    sees the submap it would have built itself, and the cache fills as it would have."""

    def __init__(
        self, size: int = 32, tolerance: float = 0.01, max_bytes: int = 8 * 2**20
    ) -> None:
        self.size = size
        self.tolerance = tolerance
        self.max_bytes = max_bytes
        self._items: OrderedDict[tuple[int, tuple[int, ...]], Submap] = OrderedDict()
        self._bytes = 0
        self._ahead: Submap | None = None
        self.hits = 0
        self.builds = 0
        self.prefetched = 0
        self.prefetch_used = 0

    @property
    def requests(self) -> int:
        """How many submaps checks have asked for (:meth:`get`)."""
        return self.hits + self.builds

    def get(
        self,
        poses: FloatArray,
        payloads: Sequence[FloatArray | None],
        anchor: int,
        members: Sequence[int],
        config: LoopClosureConfig,
    ) -> Submap:
        key = (anchor, tuple(members))
        layout = _layout(poses, anchor, key[1])
        known = self._items.get(key)
        if known is not None and _same_layout(known.layout, layout, self.tolerance):
            self._items.move_to_end(key)
            self.hits += 1
            return known
        built = self._take_ahead(key, layout)
        if built is None:
            built = _build_submap(poses, payloads, anchor, key[1], layout, config)
        if known is not None:
            self._bytes -= _submap_bytes(known)
        self._items[key] = built
        self._items.move_to_end(key)
        self._bytes += _submap_bytes(built)
        while len(self._items) > 1 and (
            len(self._items) > self.size or self._bytes > self.max_bytes
        ):
            self._bytes -= _submap_bytes(self._items.popitem(last=False)[1])
        self.builds += 1
        return built

    def prefetch(
        self,
        poses: FloatArray,
        payloads: Sequence[FloatArray | None],
        anchor: int,
        members: Sequence[int],
        config: LoopClosureConfig,
    ) -> bool:
        """Build the submap a check to ``anchor``'s place is about to ask :meth:`get` for,
        unless the cache or the one built ahead already holds it as it stands; returns
        whether it was built."""
        key = (anchor, tuple(members))
        if self.size <= 0 or key in self._items:
            return False  # (a check finds it there, or rebuilds it as it would have)
        layout = _layout(poses, anchor, key[1])
        ahead = self._ahead
        if ahead is not None and _key(ahead) == key and np.array_equal(ahead.layout, layout):
            return False
        self._ahead = _build_submap(poses, payloads, anchor, key[1], layout, config)
        if config.polish:
            self._ahead.lines()  # what an accepted check is polished on: most are accepted
        self.prefetched += 1
        return True

    def _take_ahead(self, key: tuple[int, tuple[int, ...]], layout: FloatArray) -> Submap | None:
        """The submap built ahead for ``key``, if its members lie exactly at ``layout``."""
        ahead = self._ahead
        if ahead is None or _key(ahead) != key:
            return None
        self._ahead = None
        if not np.array_equal(ahead.layout, layout):
            return None  # the map moved the pass since: built again, as the check would
        self.prefetch_used += 1
        return ahead


def _key(submap: Submap) -> tuple[int, tuple[int, ...]]:
    return submap.anchor, submap.members


def _layout(poses: FloatArray, anchor: int, members: Sequence[int]) -> FloatArray:
    """The ``members``' poses relative to ``anchor``'s, as the map holds them now."""
    return np.array([between(poses[anchor], poses[m]) for m in members])


def _build_submap(
    poses: FloatArray,
    payloads: Sequence[FloatArray | None],
    anchor: int,
    members: tuple[int, ...],
    layout: FloatArray,
    config: LoopClosureConfig,
) -> Submap:
    reg = config.registration
    points = fuse_submap(poses, payloads, anchor, members, config.submap_spacing)
    seen = SeenArea(poses, payloads, anchor, members, reg.resolution * 2**reg.score_level)
    pyramid = _submap_pyramid(points, reg) if points.shape[0] >= 3 else None
    return Submap(anchor, members, layout, points, seen, pyramid)


def _submap_bytes(submap: Submap) -> int:
    pyramid = submap.pyramid.nbytes if submap.pyramid is not None else 0
    seen = submap.seen.mask.nbytes + submap.seen.facing.nbytes
    return pyramid + submap.points.nbytes + seen


def _same_layout(a: FloatArray, b: FloatArray, tolerance: float) -> bool:
    if a.shape != b.shape:
        return False
    if not a.size:
        return True
    moved = np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1])
    turned = np.abs(wrap_angle(a[:, 2] - b[:, 2]))
    return bool(np.all(moved <= tolerance) and np.all(turned <= tolerance))


# the mask of :func:`nearest_experience` that stands for every experience
_ALL_USABLE = np.zeros(0, dtype=np.bool_)

#: starts each way along the line from the map's prediction to a far correction
#: (:func:`_prediction_peak_rivals`), a quarter of the rival distance apart
_PEAK_STARTS = 4


def nearest_experience(
    poses: FloatArray,
    travelled: FloatArray,
    position: FloatArray,
    now: float,
    radius: float,
    min_travel: float,
    verifiable: NDArray[np.bool_] | None = None,
) -> int | None:
    """The experience nearest ``position`` (map frame) within ``radius`` metres among those
    made at least ``min_travel`` metres of travel ago (a place just left is no loop), or None.
    ``verifiable``: which experiences a check can register against (all when None); one
    without a scan of its own is passed over for the nearest that has one, not proposed in
    vain (exp1.dat came back within 0.13 m of its first place, whose scan is not kept, and no
    check ran).
    """
    old = int(np.searchsorted(travelled, now - min_travel, side="right"))
    usable = _ALL_USABLE if verifiable is None else verifiable
    best = _nearest_within(poses, old, float(position[0]), float(position[1]), radius, usable)
    return None if best < 0 else best


def first_marked_experience(
    poses: FloatArray, travelled: FloatArray, position: FloatArray, now: float, radius: float,
    min_travel: float, marked_at: FloatArray, start: int = 0,
) -> int | None:
    """The oldest experience from ``start`` on within ``radius`` metres of ``position`` (map
    frame) that was made, and marked (``marked_at``: the travel it was marked at, inf for
    none), at least ``min_travel`` metres of travel ago, or None: where the robot passes
    again after a check to the place it came back to was refused, the map holds the area
    twice, and the nearest experience is the new copy."""
    old = int(np.searchsorted(travelled, now - min_travel, side="right"))
    x, y = float(position[0]), float(position[1])
    first = _first_within(poses, start, old, x, y, radius, marked_at, now - min_travel)
    return None if first < 0 else first


@njit(cache=True)
def _first_within(
    poses: FloatArray, start: int, count: int, x: float, y: float, radius: float,
    marked_at: FloatArray, before: float,
) -> int:
    # as _nearest_within: probed at every scan between looks
    r2 = radius * radius
    for i in range(start, count):
        if not marked_at[i] <= before:
            continue
        dx = poses[i, 0] - x
        dy = poses[i, 1] - y
        if dx * dx + dy * dy <= r2:
            return i
    return -1


@njit(cache=True)
def _nearest_within(
    poses: FloatArray, count: int, x: float, y: float, radius: float, usable: NDArray[np.bool_]
) -> int:
    # One pass over the first ``count`` poses without temporaries: the cue is probed at
    # every scan between looks, where a few NumPy calls would cost more than the odometry.
    # An empty ``usable`` stands for all.
    best = -1
    best_d2 = radius * radius
    for i in range(count):
        if usable.size > 0 and not usable[i]:
            continue
        dx = poses[i, 0] - x
        dy = poses[i, 1] - y
        d2 = dx * dx + dy * dy
        if d2 <= best_d2 and (best < 0 or d2 < best_d2):  # the first of equals, as argmin
            best_d2 = d2
            best = i
    return best


@dataclass(frozen=True)
class Check:
    """One verification as the system ran it: when (``stamp``), of which experience (and
    when that was made), with which cue ('view' or 'proximity'), and its verdict."""

    stamp: float
    experience: int
    experience_stamp: float
    cue: str
    verdict: Verdict


def slides(checks: Sequence[Check]) -> FloatArray:
    """(N, 2) each check's slide in its place's frame (:attr:`Verdict.free`), NaN for a
    whole one: the ``free`` of :func:`bioslam.evaluation.relative_pose_errors`."""
    out = np.full((len(checks), 2), np.nan)
    for k, check in enumerate(checks):
        if check.verdict.free is not None:
            out[k] = check.verdict.free
    return out


def place_covariance(
    covariance: ArrayLike, registered: ArrayLike, anchor_in_place: ArrayLike
) -> FloatArray:
    """The covariance (3x3) of a recognised place's pose in the robot's frame, from a
    registration's ``covariance`` of the robot's pose ``registered`` in the submap anchor's
    frame, the anchor being at ``anchor_in_place`` in the place's frame: the loop link runs
    from the robot to the place, so its error is the registration's seen from the robot
    (first order; the heading's error also swings the place around the robot by its
    distance)."""
    cov = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    base = np.asarray(registered, dtype=np.float64).reshape(3)
    anchor = np.asarray(anchor_in_place, dtype=np.float64).reshape(3)
    step = 1e-6
    deltas = np.vstack([np.eye(3), -np.eye(3)]) * step
    seen = inverse(compose(np.broadcast_to(anchor, (6, 3)), base + deltas))
    diff = seen[:3] - seen[3:]
    diff[:, 2] = wrap_angle(diff[:, 2])
    jacobian = diff.T / (2.0 * step)
    return jacobian @ cov @ jacobian.T


@dataclass(frozen=True)
class Verdict:
    """The outcome of verifying one candidate: ``pose`` is the robot in the candidate
    experience's frame; ``score`` the share of its points on the submap; ``ambiguity`` the
    best distinct rival's search score over the best's; ``reason`` says why a candidate was
    refused ('' when accepted); ``prior_score`` the score of the map's prediction refined
    where it stands; ``covariance`` the registration's own 3x3 covariance of ``pose`` in the
    frame it was registered in (the submap's, :attr:`MatchReport.covariance`; NaN when the
    match had too few points), from which the loop link's information is made;
    ``needs_partner`` whether an accepted one scored below ``min_score`` (at least
    ``partner_score``) and so is a closure only once another agrees with it; ``free``, where
    the registration left the position free along one direction (a corridor seen along its
    axis, :func:`sliding`), that slide's unit direction in ``pose``'s frame of reference: an
    accepted one (:attr:`partial`) pins the rest only
    (:attr:`bioslam.cognitive_map.Measurement.partial`).

    The covariance follows the scan's fit to the submap: along a corridor, where the match
    slides, it is large, across it small (maze, SICK scanner: closures 7-10 cm off along a
    corridor came with a standard deviation of 15-30 cm there)."""

    accepted: bool
    pose: FloatArray
    score: float
    ambiguity: float
    reason: str = ""
    prior_score: float = float("nan")
    covariance: FloatArray = field(default_factory=lambda: np.full((3, 3), np.nan))
    needs_partner: bool = False
    free: FloatArray | None = None

    @property
    def partial(self) -> bool:
        """Whether the registration left a slide free (it has a ``free`` direction)."""
        return self.free is not None


def verify(
    reference: FloatArray,
    query: FloatArray,
    predicted: FloatArray,
    window: tuple[float, float],
    config: LoopClosureConfig,
    seen: SeenArea | None = None,
    pyramid: MapPyramid | None = None,
    rival_window: tuple[float, float] | None = None,
    slide_rival_window: tuple[float, float] | None = None,
) -> Verdict:
    """Register ``query`` (the current scan, robot frame) against ``reference`` (a submap in
    a candidate experience's frame) within ``window`` (m, rad) of ``predicted``, and judge it.

    The window is searched whole by the wide-basin matcher (branch and bound,
    :mod:`bioslam.matching.branch_and_bound`), which also reports the best distinct rival;
    Gauss-Newton refines the winner on the points that land where the submap looked
    (:func:`refine_where_seen`). Accepted only when the result fits (``min_score`` of the
    points land on the submap; from ``partner_score`` up it is accepted needing a partner,
    :attr:`Verdict.needs_partner`), is constrained in every direction (not degenerate; with
    ``reject_degenerate`` off, a slide along a corridor is judged on what it pins instead, a
    partial closure), and
    no distinct pose in the window fits nearly as well (``rival / best < max_ambiguity``): in a
    corridor or among identical rooms the scan alone cannot say where it is, and a false
    closure bends the whole map. Likewise the map's own prediction, refined where it stands,
    is a rival: a best pose away from it must score more than ``prior_margin`` above it, and
    one nearer than the rival distance more than ``prior_tie`` (else the refined prediction
    is the verdict's pose).

    ``seen``: where the submap's scans looked; points of the current scan elsewhere are not
    judged (:class:`SeenArea`, :func:`seen_hit_fraction`). None judges every point.
    ``pyramid``: ``reference`` already rasterised (:class:`Submap`), else built here.
    ``rival_window``: where the map's prediction may be farther off than ``window`` (m, rad; capped
    at ``outside_rival_distance`` and ``outside_rival_angle``): an accepted pose is then challenged
    by the best poses outside ``window`` within it (:func:`outside_rival`). A window that holds a
    look-alike but not the true place has no rival in it (the maze's SICK route: the map 0.98 m off
    along a corridor, a 0.4 m window, the look-alike at the prediction); the true place outside then
    fits as well, and the check is refused as ambiguous.
    ``slide_rival_window``: the same for a registration that slides (a partial closure,
    :func:`_partial_verdict`), whose pose along the slide is the prediction's: where the map may
    be farther off across it than ``window`` (:class:`bioslam.slam.BioSLAM` passes it across
    the odometry's breaks only: a step the odometry merely doubted slides it along a
    corridor, which a partial closure claims nothing about)."""
    reg = config.registration
    distance, angle = _searched_window(window, config)
    pyramid = pyramid or _submap_pyramid(reference, reg)
    outside = _outside_window((distance, angle), rival_window, config)
    # pooled and cropped for the widest window any search of this check reaches
    sliding_outside = _outside_window((distance, angle), slide_rival_window, config)
    reach = [w for w in ((distance, angle), outside, sliding_outside) if w is not None]
    widest = (max(w[0] for w in reach), max(w[1] for w in reach))
    searcher = _searcher(pyramid, query, predicted, widest, config)
    found = _wide_search(searcher, query, predicted, (distance, angle), config)
    judge = pyramid.grids[reg.score_level]
    pose, report = refine_where_seen(
        pyramid, found.pose, query, _searched_levels(pyramid, config), seen
    )
    # The map's own prediction, refined where it stands. Along a corridor the window's best
    # may lie on a plateau the scan barely constrains, far from the truth and with no
    # distinct lattice rival (Gauss-Newton may also slide along it): a correction away from
    # the prediction must fit clearly better than the prediction itself. The two are
    # compared on every point: judged only where the submap looked, a pose that pushes
    # points out of its sight would gain by it.
    kept, kept_report = refine_where_seen(
        pyramid, predicted, query, levels_up_to(reg.max_iterations, 0), seen
    )
    if report.degenerate and not config.reject_degenerate and sliding(report.degenerate_direction):
        return _partial_verdict(
            pose, report, found, pyramid, query, (predicted, kept), (distance, angle), config,
            seen, slide_rival_window, searcher,
            unsearched=(distance, angle) != (window[0], window[1]),  # the window was cut
        )  # fmt: skip
    fit, kept_fit = (seen_hit_fraction(judge, p, query, reg.hit_level) for p in (pose, kept))
    agree = within(between(kept, pose), config.rival_distance, config.rival_angle)
    if agree and kept_fit >= fit - config.prior_tie:
        # Near the prediction, the prediction refined fits as well: the window's best is
        # then another point of the same plateau (along a corridor), not a measured
        # correction, and moving the map there would inject its error.
        pose, fit, report = kept, kept_fit, kept_report
    # near enough to the prediction refined that the tie above decided; farther, though
    # within the rival distance, a correction must earn the margin as a distinct one does
    tied = within(between(kept, pose), config.tie_distance, config.tie_angle)
    score = seen_hit_fraction(judge, pose, query, reg.hit_level, seen, config.min_seen)
    kept_score = seen_hit_fraction(judge, kept, query, reg.hit_level, seen, config.min_seen)
    slid = not within(between(found.pose, pose), 2.0 * found.resolution, config.rival_angle)
    # the prediction refined fits the place: it may have stopped short of its peak
    search_near_prediction = (
        not agree
        and config.search_prediction_plateau
        and kept_score >= config.partner_score
    )
    reason = ""
    if score < min(config.min_score, config.partner_score):
        reason = "score"
    elif report.degenerate:  # one that turns (a slide returned above, when accepted)
        reason = "degenerate"
    elif (
        found.ambiguity >= config.max_ambiguity
        or (not tied and kept_fit >= fit - config.prior_margin)
        # ... and where the submap looked: a 180° scanner passing the other way sees beyond
        # what the old pass saw, and on every point a pose 1.3-1.5 m along a corridor that
        # puts those points onto the submap's walls outscored the prediction refined, 1-3 cm
        # from the truth, by more than the margin, while where the submap looked it fitted
        # within 0.01-0.03 of it (maze, SICK scanner, weaving route)
        or (not tied and kept_score >= score - config.prior_margin)
        # the prediction fits better where the submap looked, the chosen pose on every
        # point: what the submap saw does not decide between them (freiburg-079: a 1.4 m
        # slide along a corridor)
        or kept_score > score + config.prior_tie
    ):
        reason = "ambiguous"
    elif slid and not agree:
        reason = "slid"
    elif not within(between(predicted, pose), distance, angle):
        reason = "beyond drift"
    elif (
        search_near_prediction
        and _prediction_peak_rivals(pyramid, query, predicted, pose, seen, (fit, score), config)
    ) or (
        outside is not None
        and outside_rival(
            pyramid, query, predicted, (distance, angle), rival_window, fit, config, seen,
            searcher, looked=score, known=found,
        )
    ):
        reason = "ambiguous"
    elif (
        rival_window is None
        and config.challenge_trusted
        and score >= config.min_score
        # A check the odometry vouches for has no rival window, but where the scan barely
        # pins the motion the odometry can slide past its drift bound unflagged (serpentine
        # corridor, UTM-30LX: a reversal taken as going on, the map 1.40 m off along the
        # corridor in a 0.36 m window; the prediction refined fitted 0.899 on every point and
        # 0.943 where the submap looked, the true place outside 0.952 and 0.971). Challenged
        # along its position as far as a check across breaks is, within its own angle (the
        # slide is a translation; the walls pin the heading). Only a check that fits well
        # enough to close alone: below ``min_score`` a look-alike often fits better than the
        # true place (identical rooms, SICK: a twin room 2.4 m off 0.12 better on every point
        # and 0.045 where the submap looked than the true place, 0.8 cm off), and such a
        # check waits for a partner anyway.
        and outside_rival(
            pyramid, query, predicted, (distance, angle), (config.outside_rival_distance, angle),
            fit, config, seen, looked=score, better=True, known=found,
        )
    ):
        reason = "beyond drift"
    return Verdict(
        not reason, pose, score, found.ambiguity, reason, kept_score, report.covariance.copy(),
        needs_partner=score < config.min_score,
    )  # fmt: skip


def _searched_levels(pyramid: MapPyramid, config: LoopClosureConfig) -> tuple[int, ...]:
    """Gauss-Newton's iterations per level from a pose the wide-basin search found: on the
    searched level and finer only, since a coarser level's blur would let it slide along a
    corridor, away from what the search found."""
    level = min(config.search_level, len(pyramid.grids) - 1)
    return levels_up_to(config.registration.max_iterations, level)


def _prediction_peak_rivals(
    pyramid: MapPyramid,
    query: FloatArray,
    predicted: FloatArray,
    accepted: FloatArray,
    seen: SeenArea | None,
    scores: tuple[float, float],
    config: LoopClosureConfig,
) -> bool:
    """Whether a peak near the map's prediction rivals the ``accepted`` correction beyond
    the rival distance (``scores``: its share on every point and where the submap looked):
    refined (Gauss-Newton, where the submap looked) from starts along the line to it within
    the rival distance of the prediction, and farther than that from the correction (not
    its own peak's shoulder), it fits within ``prior_margin`` of it. The prediction refined
    where it stands (:func:`verify`) stops where the scan stops pinning it: along an aisle
    0.30 m from its true place, fitting 0.840 where the submap looked, while the true place
    fitted 0.945 refined and a look-alike 2.8 m along the aisle 0.955 (the built-in
    warehouse, SICK, reversing route kept every third scan, seed 630: two such closures,
    13.3 cm of error against the odometry's 1.0; a third, its prediction refined 24 cm
    uncertain along the aisle but not flagged degenerate, when the first two were refused).
    The line is where such a slide lies; the wide-basin search near the prediction, which
    scores every point, ran to the window's edge toward the look-alike, where more of the
    scan lands on the submap."""
    reg = config.registration
    judge = pyramid.grids[reg.score_level]
    toward = unit(accepted[:2] - predicted[:2])
    iterations = _searched_levels(pyramid, config)
    fit, score = scores
    for step in np.linspace(-1.0, 1.0, 2 * _PEAK_STARTS + 1) * config.rival_distance:
        start = predicted.copy()
        start[:2] += step * toward
        pose, _ = refine_where_seen(pyramid, start, query, iterations, seen)
        if not within(between(predicted, pose), config.rival_distance, config.rival_angle):
            continue
        if within(between(accepted, pose), config.rival_distance, config.rival_angle):
            continue  # the accepted pose's own peak
        if _outfits(judge, pose, query, fit, score, seen, config, False, config.prior_margin):
            return True
    return False


def _partial_verdict(
    pose: FloatArray,
    report: MatchReport,
    found: _Found,
    pyramid: MapPyramid,
    query: FloatArray,
    prediction: tuple[FloatArray, FloatArray],
    window: tuple[float, float],
    config: LoopClosureConfig,
    seen: SeenArea | None,
    rival_window: tuple[float, float] | None = None,
    searcher: WideBasinMatcher | None = None,
    unsearched: bool = False,
) -> Verdict:
    """The verdict on a registration that slides (a corridor seen along its axis,
    :func:`sliding`): what it pins, the position across the slide and the heading, taken
    from the refined ``pose``, and along the slide the map's prediction's, where the scan
    fits as well (a partial closure, :attr:`Verdict.partial`). ``prediction``: the map's
    predicted pose and that pose refined where it stands (as :func:`verify` refines it).
    Refused when it fits too little, when the search's rival differs from it in what it pins
    (another corridor beside, or one turned: a rival along the slide is the same corridor),
    or when its correction is beyond ``window``; with a ``rival_window`` (the odometry does not
    vouch for the prediction, :func:`verify`), also when a pose outside ``window`` there fits
    as well and differs from the prediction in what the slide pins (a corridor beside, the
    truth outside a window the map's error left it; one further along the slide is the same
    corridor, which the verdict claims nothing about, :func:`outside_rival` with ``free``),
    or when its slide bends (:func:`slide_bend`). ``unsearched``: the map's prediction may
    lie farther off than the search reached (its window cut to ``search_distance`` /
    ``search_angle``); then it may only confirm the prediction refined, not move the map."""
    predicted, kept = prediction
    reg = config.registration
    free = unit(report.degenerate_direction)  # in the submap's frame
    start = pose.copy()
    start[:2] -= free * float((pose[:2] - predicted[:2]) @ free)
    # moved along the slide to the prediction, refined again: the slide's direction is
    # only the weakest one's position part, and that turns a little with the heading
    finest = levels_up_to(reg.max_iterations, 0)
    pinned, pinned_report = refine_where_seen(pyramid, start, query, finest, seen)
    matched = pinned_report.num_points
    judge = pyramid.grids[reg.score_level]
    score = seen_hit_fraction(judge, pinned, query, reg.hit_level, seen, config.min_seen)
    # The map's prediction refined where it stands is a rival in what the slide pins, as
    # for a whole closure (:func:`verify`): a correction it does not share must fit clearly
    # better than it, else the scan cannot tell the place from a corridor beside it or a
    # heading the plateau tilts to (maze, SICK: a slide turned 4.4 deg from a prediction
    # that was right fitted 0.946 against 0.914). Its pose is no measurement itself: along
    # a corridor its refinement holds the weak direction, heading and all.
    kept_score = seen_hit_fraction(judge, kept, query, reg.hit_level, seen, config.min_seen)
    tied = within(_across(kept, pinned, free), config.tie_distance, config.partial_tie_angle)
    reason = ""
    if score < min(config.min_score, config.partner_score):
        reason = "score"
    elif unsearched and not tied:
        # Along the slide the pose is the prediction's, which may lie farther off than the
        # search looked: a correction across it or a turn then comes from places the search
        # never weighed against the one that may be the robot's (a ring of corridors, the
        # odometry lost by 7 m: a window of 6.9 m cut to 3, a closure turning the map by 21°
        # that left it 3.6 m across its slide and 28° off, at 0.92 against the prediction
        # refined's 0.32). One that confirms the prediction refined moves nothing.
        reason = "ambiguous"
    elif slide_bend(pyramid, pinned, query, free, finest, seen, matched) * window[0] > (
        config.partial_tie_angle
    ):
        # The plateau bends (a curved corridor, where the heading changes with the place
        # along it): the slide pins no heading, and the prediction's place, as far off along
        # it as the window allows, sets one as far off (a curved floor's thinned SICK tour:
        # closures 1.4 and 3.6 m along their corridor, 6.9 and 16.3° off the truth at 0.95
        # and 1.0).
        reason = "degenerate"
    elif not tied and kept_score >= score - config.prior_margin:
        reason = "ambiguous"
    elif (
        found.ambiguity >= config.max_ambiguity
        and found.rival_pose is not None
        and not within(_across(found.rival_pose, found.pose, free), config.tie_distance,
                       config.tie_angle)
    ):  # fmt: skip
        reason = "ambiguous"
    if not reason and not within(between(predicted, pinned), *window):
        reason = "beyond drift"
    if not reason and rival_window is not None and outside_rival(
        pyramid, query, predicted, window, rival_window,
        seen_hit_fraction(judge, pinned, query, reg.hit_level), config, seen, searcher,
        looked=score, free=free, known=found,
    ):  # fmt: skip
        # the map's prediction not vouched for: another corridor beside, outside the window
        # but within what the odometry's breaks may have moved it, fits as well
        reason = "ambiguous"
    return Verdict(
        not reason, pinned, score, found.ambiguity, reason, kept_score,
        report.covariance.copy(), needs_partner=score < config.min_score, free=free,
    )  # fmt: skip


#: metres along a slide that :func:`slide_bend` moves a registration either way to see it turn
SLIDE_PROBE = 1.0


def slide_bend(
    pyramid: MapPyramid,
    pose: FloatArray,
    query: FloatArray,
    free: FloatArray,
    iterations: tuple[int, ...],
    seen: SeenArea | None,
    matched: int,
) -> float:
    """How fast (rad per metre) a registration that slides along the unit ``free``
    direction turns along its slide: refined again (``iterations`` per level) from ``pose``
    moved :data:`SLIDE_PROBE` either way along it. A bend turns it both ways apart (along a
    curved corridor of radius R, 1 / R each way), the lesser turn over the distance is the
    bend; none where both turn alike, or where either matched fewer than half of
    ``matched`` points (``pose``'s): moved off what the submap saw, its heading says nothing
    of the corridor (a straight one's probes so turned 1.5-4° one way only)."""
    turns = []
    for sign in (1.0, -1.0):
        start = np.asarray(pose, dtype=np.float64).copy()
        start[:2] += sign * SLIDE_PROBE * free
        moved, report = refine_where_seen(pyramid, start, query, iterations, seen)
        if 2 * report.num_points < matched:
            return 0.0
        turns.append(float(wrap_angle(moved[2] - pose[2])))
    if turns[0] * turns[1] >= 0.0:
        return 0.0
    return min(abs(t) for t in turns) / SLIDE_PROBE


def _across(a: ArrayLike, b: ArrayLike, free: FloatArray | None) -> FloatArray:
    """How pose ``a`` differs from pose ``b`` (same frame) in what a slide along the unit
    ``free`` direction pins: the position across it and the heading (None: the whole
    difference, in the frame they are given in)."""
    apart = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    if free is not None:
        apart[:2] -= free * float(apart[:2] @ free)
    apart[2] = wrap_angle(apart[2])
    return apart


#: A degenerate direction whose position part carries at least this share of its (unit)
#: length is a slide (along a corridor), which a partial closure can leave free; one that
#: turns as well (a round room) leaves the heading unpinned, and is refused.
SLIDING_SHARE = 0.9


def sliding(direction: ArrayLike) -> bool:
    """Whether a registration's degenerate ``direction`` (unit, (x, y, θ · length scale),
    :attr:`MatchReport.degenerate_direction`) is a slide of the position with the heading
    pinned (:data:`SLIDING_SHARE`)."""
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    return bool(math.hypot(d[0], d[1]) >= SLIDING_SHARE * float(np.linalg.norm(d)) > 0.0)


@dataclass(frozen=True)
class _Found:
    """The wide-basin search's answer (``match``; a wider window's search reuses it) and its
    lattice spacing."""

    match: WideMatch
    resolution: float

    @property
    def pose(self) -> FloatArray:
        """The best lattice pose."""
        return self.match.pose

    @property
    def ambiguity(self) -> float:
        """The best distinct rival's score over the best's."""
        return self.match.ambiguity

    @property
    def rival_pose(self) -> FloatArray | None:
        """The best distinct rival's lattice pose, if any."""
        return self.match.rival_pose


def _searcher(
    pyramid: MapPyramid,
    query: FloatArray,
    centre: FloatArray,
    window: tuple[float, float],
    config: LoopClosureConfig,
) -> WideBasinMatcher:
    """A wide-basin matcher with the search level pooled where ``query``'s points can land
    from ``window`` (m, rad) around ``centre``: once for every window within it (a check's
    own and the wider one its rival is sought in), and over that reach alone, which on a
    large building's submap is a fraction of the grid."""
    matcher = WideBasinMatcher(_window_config(window, config))
    grid = pyramid.grids[min(config.search_level, len(pyramid.grids) - 1)]
    matcher.set_map(grid, matcher.reach_box(query, [(centre, *window)], grid.resolution))
    return matcher


def _window_config(
    window: tuple[float, float], config: LoopClosureConfig, rival_floor: float | None = None
) -> WideBasinConfig:
    """The search of ``window`` (m, rad), its rivals sought down to ``rival_floor`` of the
    best (``max_ambiguity`` by default: below it no rival decides a verdict)."""
    return WideBasinConfig(
        distance=window[0],
        angle=window[1],
        rival_distance=config.rival_distance,
        rival_angle=config.rival_angle,
        min_rival_ratio=config.max_ambiguity if rival_floor is None else rival_floor,
    )


def _searched_window(
    window: tuple[float, float], config: LoopClosureConfig
) -> tuple[float, float]:
    """The part of a check's ``window`` (m, rad) its registration searches: no wider than
    ``search_distance`` and ``search_angle``."""
    return min(window[0], config.search_distance), min(window[1], config.search_angle)


def _wide_search(
    matcher: WideBasinMatcher,
    query: FloatArray,
    centre: FloatArray,
    window: tuple[float, float],
    config: LoopClosureConfig,
    slide: FloatArray | None = None,
    known: _Found | None = None,
    rival_floor: float | None = None,
) -> _Found:
    """Branch and bound over ``window`` (m, rad) around ``centre`` with ``matcher``, pooled
    for it or a wider window (:func:`_searcher`); ``slide``: its rival is sought across it;
    ``known``: its search of a window within this one, reused
    (:meth:`WideBasinMatcher.search`); ``rival_floor``: as :func:`_window_config`'s."""
    matcher.config = _window_config(window, config, rival_floor)
    found = matcher.search(query, centre, slide=slide, known=None if known is None else known.match)
    return _Found(found, matcher.resolution)


def clear_of_rivals(
    pyramid: MapPyramid,
    query: FloatArray,
    predicted: FloatArray,
    window: tuple[float, float],
    config: LoopClosureConfig,
) -> bool:
    """Whether no distinct pose within ``window`` (m, rad, capped at the search's) around
    ``predicted`` fits ``query`` within ``clear_ambiguity`` of the window's best: a check
    that passes the rival test clearly, not by a hair (:meth:`bioslam.slam.BioSLAM._accepted`
    lets such a check stand at a place found ambiguous moments before). The window is
    searched again with its rivals sought down to that share, which the check's own search
    (down to ``max_ambiguity``) did not."""
    searched = _searched_window(window, config)
    matcher = _searcher(pyramid, query, predicted, searched, config)
    found = _wide_search(
        matcher, query, predicted, searched, config, rival_floor=config.clear_ambiguity
    )  # fmt: skip
    return found.match.rival_pose is None


def _outside_window(
    window: tuple[float, float],
    rival_window: tuple[float, float] | None,
    config: LoopClosureConfig,
) -> tuple[float, float] | None:
    """The window (m, rad) :func:`outside_rival` searches around a check's ``window``, where
    the map's prediction may be off by ``rival_window`` (capped at ``outside_rival_distance``
    and ``outside_rival_angle``); None when that reaches no farther than ``window``."""
    if rival_window is None:
        return None
    wide = (
        max(window[0], min(rival_window[0], config.outside_rival_distance)),
        max(window[1], min(rival_window[1], config.outside_rival_angle)),
    )
    return None if wide[0] <= window[0] and wide[1] <= window[1] else wide


def outside_rival(
    pyramid: MapPyramid,
    query: FloatArray,
    predicted: FloatArray,
    window: tuple[float, float],
    rival_window: tuple[float, float],
    fit: float,
    config: LoopClosureConfig,
    seen: SeenArea | None = None,
    searcher: WideBasinMatcher | None = None,
    looked: float | None = None,
    better: bool = False,
    free: FloatArray | None = None,
    known: _Found | None = None,
) -> bool:
    """Whether a pose outside ``window`` (m, rad) around ``predicted`` but within ``rival_window``
    (capped at ``outside_rival_distance`` and ``outside_rival_angle``) fits ``query`` as well as
    the pose accepted in it, to within ``prior_tie`` (the score's own noise): on every point
    (share ``fit`` on the submap) or, given ``looked``, where the submap looked (its score
    there, :func:`seen_hit_fraction` with ``seen``). Where the submap looked decides too: a scan
    turned the other way sees much the submap never did, and at the true place those points
    count as misses on every point while a look-alike 3 m on puts them on other walls (the
    URG-04LX hall's reversing route: the true place 0.74-0.80 on every point against the
    accepted look-alike's 0.95, 0.98 where the submap looked against its 0.96). The best and the
    best distinct rival of a search over the wider window are refined (Gauss-Newton, as the
    accepted pose) where they lie outside ``window``. Where the odometry may have slid farther
    than the drift bound (blind along a corridor), the window's lone fit may be a look-alike of
    the place outside it; the place itself then fits at least as well as its look-alike,
    whatever the world, and the scan cannot say which it is. A pose outside that fits clearly
    worse is no such place: the window, which the map's prediction favours, keeps its fit (with
    ``prior_margin`` instead, the URG-04LX hall lost half its recognised revisits, 0.327 ->
    0.163). ``searcher``: the search level already pooled for the wider window
    (:func:`_searcher`), else pooled here.

    ``better``: the pose outside must fit clearly better instead, by more than ``prior_tie``
    both on every point and where the submap looked: the challenge of a check the odometry
    vouches for, whose window a look-alike outside must not empty (on every point alone, a
    360° scanner's look-alikes 2-3 m along a library's aisles fitted 0.04-0.06 better than the
    true place, where the submap looked 0.1 worse).

    ``free``: a partial closure's slide (unit, the submap's frame): a pose that differs from
    ``predicted`` beyond ``window`` only along it is the same corridor, no rival; the search's
    rival is sought across it (a corridor beside), the corridor's own plateau left out.

    ``known``: the search of ``window`` the check made (:func:`verify`), which the wider
    search reuses (:meth:`WideBasinMatcher.search`; its answer is the same)."""
    wide = _outside_window(window, rival_window, config)
    if wide is None:
        return False
    reg = config.registration
    searcher = searcher or _searcher(pyramid, query, predicted, wide, config)
    found = _wide_search(searcher, query, predicted, wide, config, free, known)
    iterations = _searched_levels(pyramid, config)
    judge = pyramid.grids[reg.score_level]
    for start in (found.pose, found.rival_pose):
        if start is None or within(_across(start, predicted, free), *window):
            continue
        pose, _ = refine_where_seen(pyramid, start, query, iterations, seen)
        if within(_across(pose, predicted, free), *window):
            continue  # slid back into the window: the accepted pose's own peak
        if _outfits(judge, pose, query, fit, looked, seen, config, better):
            return True
    return False


def _outfits(
    judge: OccupancyGrid,
    pose: FloatArray,
    query: FloatArray,
    fit: float,
    looked: float | None,
    seen: SeenArea | None,
    config: LoopClosureConfig,
    better: bool,
    margin: float | None = None,
) -> bool:
    """Whether ``query`` at ``pose`` fits as well as the accepted pose, to within ``margin``
    (None: ``prior_tie``), on every point (``fit``) or, given ``looked``, where the submap
    looked; or, ``better``, clearly better on both (:func:`outside_rival`). Each score is
    computed only when the ones before have not decided."""
    reg = config.registration

    def gain(where_looked: bool) -> float:
        if where_looked:
            there = seen_hit_fraction(judge, pose, query, reg.hit_level, seen, config.min_seen)
            return there - looked
        return seen_hit_fraction(judge, pose, query, reg.hit_level) - fit

    scores = (False, True) if looked is not None else (False,)
    margin = config.prior_tie if margin is None else margin
    if better:
        return all(gain(s) > margin for s in scores)
    return any(gain(s) >= -margin for s in scores)


def refine_where_seen(
    pyramid: MapPyramid,
    start: FloatArray,
    query: FloatArray,
    iterations: tuple[int, ...],
    seen: SeenArea | None,
) -> tuple[FloatArray, MatchReport]:
    """Gauss-Newton (:func:`bioslam.matching.branch_and_bound.refine`) from ``start`` on the
    points of ``query`` that land, there, where the submap's scans looked (``seen``; all
    points without it or when fewer than three do). A point where the old pass never looked
    has nothing of its own to land on, and the map function pulls it onto the nearest wall
    it did see: on the simulated maze (SICK scanner, a third of the revisit's scan unseen)
    that slid the refined pose 6-23 cm from the truth from a start within 1 cm of it; on
    the seen points alone it stayed within 1.4 cm. The report (its degeneracy too) is of
    the points matched: where the seen part is one corridor's two walls, the registration
    cannot place the robot along it, whatever else the scan shows. (Judged on the whole
    scan instead, such checks were accepted slid 20-30 cm along the corridor from the
    lattice's pose: maze, SICK scanner, ATE 1.33 cm against 0.39.) Nor are the points on
    a wall's far face (:meth:`SeenArea.faces_away`): they would pull the pose onto the face
    the old pass saw, a partition's thickness off."""
    if seen is not None:
        covered = seen.judges_scan(start, query)
        if np.count_nonzero(covered) >= 3:
            query = query[covered]
    return refine(pyramid, start, query, iterations)


def polish_on_lines(
    lines: LineMap,
    pose: FloatArray,
    query: FloatArray,
    seen: SeenArea | None,
    config: LoopClosureConfig,
) -> tuple[FloatArray, LineFit | None]:
    """``pose``, a registration of ``query`` accepted on the submap's grid, polished by
    matching the points the submap can judge there (:meth:`SeenArea.judges`) to the lines
    of its own points (:func:`bioslam.matching.point_to_line.refine_point_to_line`): the
    grid's blur pulls its optimum a fraction of a cell off, alike at every revisit of a
    place. Kept only where it stays within ``line_reach`` / ``line_reach_angle`` of
    ``pose`` on at least ``MIN_JUDGED`` points; farther, the two disagree about more than
    the blur, and the grid's pose, which the checks judged, stands. Nor where the points
    scatter about their lines by more than ``line_max_spread``
    (:class:`bioslam.matching.point_to_line.LineFit`): lines
    fitted to such points tilt and shift by more than the grid's blur. Returns the pose and
    the fit it came from (None where the grid's pose stands)."""
    points = np.asarray(query, dtype=np.float64)
    if seen is not None:
        points = points[seen.judges_scan(pose, points)]
    if points.shape[0] < MIN_JUDGED:
        return pose, None
    fit = refine_point_to_line(lines, pose, points, config.line_distance, config.line_huber)
    if (
        fit.matched < MIN_JUDGED
        or fit.spread > config.line_max_spread
        or not within(between(pose, fit.pose), config.line_reach, config.line_reach_angle)
    ):
        return pose, None
    return fit.pose, fit


def judged_shape(
    points: FloatArray, normals: FloatArray, pose: FloatArray, seen: SeenArea, ratio: float
) -> FloatArray:
    """The constraint shape (:func:`bioslam.cognitive_map.registration_shape`) of the points
    of the scan (with their ``normals``, :func:`bioslam.occupancy_grid.scan_normals`) judged
    at ``pose`` in the submap's frame (:meth:`SeenArea.judges`); of
    every point when fewer than ``MIN_JUDGED`` are. What the registration matched is what
    pins it: a robot back the other way along a row of cubicles sees partitions across the
    row, but the old pass saw only their other faces, and the closures slid 7-10 cm along
    the row while the whole scan's shape said they were pinned there, so that
    :func:`settle_weak_direction` kept the slide."""
    judged = seen.judges_scan(pose, points)
    if np.count_nonzero(judged) >= MIN_JUDGED:
        points, normals = points[judged], normals[judged]
    return registration_shape(points, normals, ratio)


def _submap_pyramid(reference: FloatArray, reg: RegistrationConfig) -> MapPyramid:
    """The submap's points as a map pyramid covering their bounding box (1 m margin)."""
    ref = np.asarray(reference, dtype=np.float64)
    lo = ref.min(axis=0) - 1.0
    hi = ref.max(axis=0) + 1.0
    pyramid = MapPyramid(reg.resolution, tuple(hi - lo), reg.levels, LogOddsConfig(), origin=lo)
    # its hits alone: the registration reads the map function and the pooled search map,
    # both of hit cells only, and where the submap's scans looked is the SeenArea's; rays
    # cast from the anchor to every point of the fused scans were two thirds of a submap's
    # cost (4.4 ms on freiburg-079) and changed nothing read
    dense = densify_scan(ref, 0.5 * reg.resolution, NORMAL_MAX_GAP)
    pyramid.insert_scan(np.zeros(3), dense, rays=False)
    return pyramid


def seen_hit_fraction(
    grid: OccupancyGrid,
    pose: FloatArray,
    query: FloatArray,
    level: float,
    seen: SeenArea | None = None,
    min_seen: float = 0.0,
) -> float:
    """The registration score: of the query's points inside the submap's grid that the
    submap's scans saw (``seen``; all of them without it) or that land on its walls, the share
    that land within about a cell of its walls (the map function at least ``level``), as
    ``register_scans`` scores.
    At least ``min_seen`` of the points inside count (as misses when unseen), so a pose that
    puts most of the scan where the submap never looked cannot pass on the few left."""
    world = transform_points(pose, query)
    values, _ = grid.value_and_gradient(world, subcell_sigma=1.0)
    far = grid.origin + grid.resolution * np.array(grid.shape[::-1])
    bounds = np.array([*grid.origin, *far]) + grid.resolution * np.array([1.0, 1.0, -1.0, -1.0])
    area = seen or _NOWHERE
    inside, hits, seen_count, seen_hits, other_count, other_hits = _judged_hits(
        values, world, np.asarray(pose, dtype=np.float64), bounds, level, area.mask,
        area.facing, area.origin, area.resolution,
    )  # fmt: skip
    if seen is None or inside == 0:
        return hits / inside if inside else 0.0
    # a point on a wall of the submap is judged (a hit) wherever it lies
    other_share = other_hits / other_count if other_count else 0.0
    seen_share = seen_hits / seen_count if seen_count else 0.0
    hit = seen_share * seen_count + other_share * other_count
    judged = seen_count + other_share * other_count
    return hit / max(judged, min_seen * inside)


@njit(cache=True)
def _judged_hits(values, world, sensor, bounds, level, mask, facing, origin, resolution):
    """:func:`seen_hit_fraction`'s counts of the points (``world``, map function
    ``values``) at least a cell inside the grid (``bounds``: xmin, ymin, xmax, ymax, that
    cell in): (inside, hits among them), and of those not on a far face
    (:meth:`SeenArea.faces_away`, seen from ``sensor``) the ones in the cells ``mask``
    says the submap saw (count, hits) and the rest (count, hits). A hit: the map function
    at least ``level``."""
    rows, cols = mask.shape
    inside = hits = seen_count = seen_hits = other_count = other_hits = 0
    for k in range(world.shape[0]):
        x, y = world[k, 0], world[k, 1]
        if not (bounds[0] <= x < bounds[2] and bounds[1] <= y < bounds[3]):
            continue
        hit = values[k] >= level
        inside += 1
        hits += hit
        col = math.floor((x - origin[0]) / resolution)
        row = math.floor((y - origin[1]) / resolution)
        covered = False
        if 0 <= col < cols and 0 <= row < rows:
            # a point on a wall's far face is judged neither way: the submap never saw it
            toward = facing[row, col, 0] * (sensor[0] - x) + facing[row, col, 1] * (sensor[1] - y)
            if toward < 0.0:
                continue
            covered = mask[row, col]
        if covered:
            seen_count += 1
            seen_hits += hit
        else:
            other_count += 1
            other_hits += hit
    return inside, hits, seen_count, seen_hits, other_count, other_hits


def score_plateau(
    grid: OccupancyGrid,
    pose: FloatArray,
    query: FloatArray,
    direction: FloatArray,
    config: LoopClosureConfig,
    seen: SeenArea | None = None,
) -> float:
    """How far (m) from ``pose`` along ``direction`` (a unit vector in the robot's frame),
    either way, the registration's score where the submap looked (:func:`seen_hit_fraction`)
    stays within ``prior_tie`` (its own noise) of its value at ``pose``, searched in steps
    of ``plateau_step`` up to ``plateau_reach``: how well the registration itself, not only
    the scan's geometry, pins the pose along that direction. Along a corridor whose end the
    submap saw from the other side, a pose 16 cm along it scored as the truth (simulated
    maze, UTM-30LX), though the end wall's points made the scan's geometry look
    constrained there."""
    reg = config.registration
    best = seen_hit_fraction(grid, pose, query, reg.hit_level, seen, config.min_seen)
    step = config.plateau_step
    widest = 0.0
    for sign in (1.0, -1.0):
        reached, t = 0.0, step
        while t <= config.plateau_reach + 1e-9:
            moved = compose(pose, np.array([sign * t * direction[0], sign * t * direction[1], 0.0]))
            score = seen_hit_fraction(grid, moved, query, reg.hit_level, seen, config.min_seen)
            if score < best - config.prior_tie:
                break
            reached, t = t, t + step
        widest = max(widest, reached)
    return widest


def weak_modes(shape: ArrayLike) -> FloatArray:
    """(3, 3) unit motions (x, y, θ; columns) of a registration, weakest first: the position
    direction its scan's geometry constrains least (``shape``, its position information,
    xx, xy, yy: :func:`bioslam.cognitive_map.registration_shape`; along a corridor, its
    axis), the turn, then the position direction it constrains most."""
    s = np.asarray(shape, dtype=np.float64).reshape(3)
    _, v = np.linalg.eigh(np.array([[s[0], s[1]], [s[1], s[2]]]))
    modes = np.zeros((3, 3))
    modes[:2, 0], modes[2, 1], modes[:2, 2] = v[:, 0], 1.0, v[:, 1]
    return modes


def settle_weak_direction(
    grid: OccupancyGrid,
    pose: FloatArray,
    predicted: FloatArray,
    query: FloatArray,
    modes: FloatArray,
    config: LoopClosureConfig,
    seen: SeenArea | None = None,
    lines: LineFit | None = None,
) -> FloatArray:
    """``pose`` (an accepted registration, in the submap's frame) with its correction of the
    map's ``predicted`` pose along each of the ``weak_modes`` weakest of ``modes``
    (:func:`weak_modes`, weakest first) taken back, unless the registration's score where
    the submap looked (:func:`seen_hit_fraction`) is more than ``weak_margin`` better with
    it than without.

    Along a corridor the score is nearly flat and Gauss-Newton, started at the map's
    prediction, slides on it: on the simulated SICK maze the closures 4-11 cm off the truth
    were all off along their corridor, by the slide itself (the prediction was 0.2-1.6 cm
    off there), and the prediction scored within 0.01-0.03 of them. Such a slide is no
    measured correction, and entered in the map it bends a loop the odometry had right;
    along the directions the score does pin, the registration keeps its correction. A
    position correction of at most ``weak_floor`` stands unjudged: the score, of hits on
    cells a tenth of a metre wide, cannot tell millimetres apart, and taking them back put
    the polished registration's millimetres back onto the prediction's (the demo's maze:
    closures 2.4 mm off the truth polished, 5.5 mm settled, the odometry between the same
    stamps 4.3 mm).

    ``lines``: the fit that polished ``pose`` on the submap's own points
    (:func:`polish_on_lines`). A position correction more than ``lines_pin`` times that fit's
    standard deviation along the mode (:meth:`LineFit.position_sigma`) stands too: the lines
    measured it, where the grid's cells could not tell it from the prediction. Down a
    warehouse aisle with the heading drifting, the polish put closures 0.1-0.6 cm from the
    truth along the aisle, and the settle put them back onto a prediction 2.4-4.4 cm off."""
    reg = config.registration
    if config.weak_margin <= 0.0:
        return pose
    scaled = np.linalg.inv(modes)  # a motion's coordinates along the modes
    here = seen_hit_fraction(grid, pose, query, reg.hit_level, seen, config.min_seen)
    for k in range(min(config.weak_modes, 3)):
        step = between(pose, predicted)
        step[2] = wrap_angle(step[2])
        along = float(scaled[k] @ step)
        position = modes[2, k] == 0.0  # (the turn is the one mode with a heading)
        if along == 0.0 or (position and abs(along) <= config.weak_floor):
            continue  # (a position correction too small for the score to judge stands)
        if position and _lines_measured(lines, pose, modes[:2, k], along, config.lines_pin):
            continue
        moved = compose(pose, along * modes[:, k])
        there = seen_hit_fraction(grid, moved, query, reg.hit_level, seen, config.min_seen)
        if there >= here - config.weak_margin:
            pose, here = moved, there
    return pose


def _lines_measured(
    lines: LineFit | None, pose: FloatArray, mode: FloatArray, along: float, pin: float
) -> bool:
    """Whether the line fit ``lines`` puts the position along ``mode`` (a unit vector in the
    frame of the registration ``pose``) more than ``pin`` standard deviations from a
    correction ``along`` metres away (0: never)."""
    if lines is None or pin <= 0.0:
        return False
    direction = rotation(float(pose[2])) @ mode  # (the submap's frame, the fit's)
    return abs(along) > pin * lines.position_sigma(direction)


def within(correction: FloatArray, distance: float, angle: float) -> bool:
    """Whether a pose correction moves by at most ``distance`` metres and ``angle`` radians."""
    return bool(np.hypot(correction[0], correction[1]) <= distance and abs(correction[2]) <= angle)


@dataclass
class Candidate:
    """A closure the verification accepted, waiting for another to confirm it
    (:class:`ClosureConsensus`): at ``stamp`` the robot was at ``measured`` in experience
    ``target``'s frame (``check``: the index of its check among the system's).
    ``odometry`` / ``target_odometry`` are the robot's odometry pose then and when
    ``target`` was made, ``travelled`` / ``target_travelled`` the odometry distance at those
    times and ``jumps`` / ``target_jumps`` the count of the odometry's breaks and other steps
    no robot can make before them (:func:`jumped`): the two chains of relative poses the
    pairwise test runs along. ``link`` is what enters the map once confirmed (opaque
    here). ``read``: the experiences whose scans its registration matched, where a partner
    that shares them cannot vouch for it (:func:`consistent`)."""

    stamp: float
    target: int
    measured: FloatArray
    odometry: FloatArray
    target_odometry: FloatArray
    travelled: float
    target_travelled: float
    jumps: int
    target_jumps: int
    link: object = None
    check: int = -1
    entered: bool = False
    read: frozenset[int] = frozenset()


def pair_residual(a: Candidate, b: Candidate) -> FloatArray:
    """How far (x, y, θ) closure ``b``'s measurement lands from what closure ``a`` and the
    odometry predict for it: ``a``'s measured pose carried along the robot's odometry from
    ``a`` to ``b`` and back along the old pass's odometry from ``a``'s experience to
    ``b``'s (the cycle of pairwise consistency, Olson 2009; Mangelson et al. 2018). Two true
    closures close this cycle to the odometry's and the registrations' error; a closure to
    a look-alike, or one that slid along a corridor, leaves the distance it is off."""
    robot = between(a.odometry, b.odometry)
    old = between(a.target_odometry, b.target_odometry)
    predicted = compose(inverse(old), compose(a.measured, robot))
    return between(predicted, b.measured)


def consistent(a: Candidate, b: Candidate, config: LoopClosureConfig) -> bool | None:
    """Whether closures ``a`` and ``b`` agree (:func:`pair_residual` within
    ``consistency_distance`` / ``consistency_angle`` plus ``consistency_per_metre`` /
    ``consistency_angle_per_metre`` times the odometry between them on both passes), or
    None when the pair cannot tell: the odometry relates them only across a break or a
    jump, over more than ``consistency_window`` metres, or they were measured less than
    ``consistency_separation`` apart (the same view twice, whose errors are one) or both
    ``read`` scans of one old experience: two checks of one look-alike 2.7 m along a
    corridor passed the other way, each a correction beyond the drift bound that only the
    odometry's breaks let in, matched three of their six scans alike and agreed (maze, SICK
    reversing, two people: three closures 4.2 m off). (Sharing scans within the drift bound,
    as most partners do, cost a pillar hall 22 of its 23 closures.)"""
    robot_span = abs(a.travelled - b.travelled)
    old_span = abs(a.target_travelled - b.target_travelled)
    if a.jumps != b.jumps or a.target_jumps != b.target_jumps:
        return None
    if max(robot_span, old_span) > config.consistency_window:
        return None
    if robot_span < config.consistency_separation or a.read & b.read:
        return None
    span = robot_span + old_span
    r = pair_residual(a, b)
    return bool(
        math.hypot(r[0], r[1]) <= config.consistency_distance + config.consistency_per_metre * span
        and abs(wrap_angle(r[2]))
        <= config.consistency_angle + config.consistency_angle_per_metre * span
    )


class ClosureConsensus:
    """Closures enter the map only in agreement (pairwise consistency, as PCM and Olson's
    single-cluster partitioning): a verified closure waits until another, measured at
    least ``consistency_separation`` metres of travel away, closes the cycle of the two
    measurements and the odometry between them (:func:`consistent`), and until as many of
    the recent closures it can be tested against agree with it as contradict it. One
    registration may fit a look-alike or slide along a corridor, however good its score;
    two at different places that agree to centimetres rarely do both by chance. A closure
    that finds no partner within ``consistency_window`` metres of travel is dropped: a
    missed closure costs little, a false one bends the map (simulated maze, SICK scanner:
    a closure 0.97 m off contradicted its neighbour by 0.91 m; URG-04LX hall: one 1.48 m
    off had none)."""

    def __init__(self, config: LoopClosureConfig) -> None:
        self.config = config
        self.recent: list[Candidate] = []

    def offer(self, candidate: Candidate, trusted: bool = False) -> list[Candidate]:
        """Judge a newly verified ``candidate``: the closures to enter the map now (the
        candidate and the waiting ones it confirms, oldest first), or [] while it waits.
        A ``trusted`` candidate enters at once (the odometry relates it to its place
        without a doubted step) and may still confirm waiting ones."""
        window = self.config.consistency_window
        self.recent = [c for c in self.recent if candidate.travelled - c.travelled <= window]
        agree, disagree = [], 0
        for other in self.recent:
            verdict = consistent(other, candidate, self.config)
            if verdict is True:
                agree.append(other)
            elif verdict is False:
                disagree += 1
        self.recent.append(candidate)
        if not trusted and (not agree or len(agree) < disagree):
            return []
        out = [c for c in agree if not c.entered] + [candidate]
        for c in out:
            c.entered = True
        return out
