"""The odometry's local map (paper Sec. III-A): the occupancy-grid pyramid each scan is fused
into and matched against, a window that scrolls with the robot, the objects kept out of it
while they move (a person walking ahead), and on sparse scans the younger submap that
replaces it when a wrong step put walls in it twice.

A mixin of :class:`bioslam.odometry.LidarOdometry`, whose state it reads (``config``,
``pose``, ``pyramid`` and the submaps' bookkeeping). No file or terminal I/O here.
"""

from __future__ import annotations

import copy
import itertools
import math
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from bioslam.geometry import between, transform_points
from bioslam.matching.gauss_newton import FloatArray, match_scan_to_map
from bioslam.matching.registration import densify_scan, densify_with_mask
from bioslam.occupancy_grid import NORMAL_MAX_GAP, MapPyramid, thinned_normals
from bioslam.odometry_config import OdometryConfig


def compact_runs(
    points: FloatArray, new: NDArray[np.bool_], gap: float, size: float
) -> list[tuple[int, int]]:
    """The runs of consecutive ``new`` ``points`` (a scan's endpoints in beam order, each
    within ``gap`` of the next) whose ends lie at most ``size`` apart and that touch no point
    that is not new (the point before or after the run, within ``gap``): objects standing
    apart from what the map holds, as (first, last) indices."""
    bounds, _ = _compact_runs(np.ascontiguousarray(points, dtype=np.float64), new, gap, size)
    return [(int(first), int(last)) for first, last in bounds]


@numba.njit(cache=True)
def _compact_runs(points, new, gap, size):
    """:func:`compact_runs` as an array of (first, last) rows, with each run's centre."""
    n = points.shape[0]
    out = np.empty((n, 2), dtype=np.int64)
    centres = np.empty((n, 2))
    count = 0
    k = 0
    while k < n:
        if not new[k]:
            k += 1
            continue
        last = k
        while last + 1 < n and new[last + 1] and _apart(points, last) <= gap:
            last += 1
        before = k > 0 and not new[k - 1] and _apart(points, k - 1) <= gap
        after = last + 1 < n and not new[last + 1] and _apart(points, last) <= gap
        extent = math.hypot(points[last, 0] - points[k, 0], points[last, 1] - points[k, 1])
        if not (before or after) and extent <= size:
            out[count, 0] = k
            out[count, 1] = last
            centres[count, 0] = points[k : last + 1, 0].mean()
            centres[count, 1] = points[k : last + 1, 1].mean()
            count += 1
        k = last + 1
    return out[:count], centres[:count]


@numba.njit(cache=True, inline="always")
def _apart(points, k):
    """The distance from point ``k`` to point ``k + 1``."""
    return math.hypot(points[k + 1, 0] - points[k, 0], points[k + 1, 1] - points[k, 1])


class Fusion(NamedTuple):
    """A scan as fused into the local map: its pose, its endpoints and their normals (sensor
    frame, those not kept out as moving objects), and whether its match left more than
    ``recovery_free_fraction`` of its endpoints in known free space."""

    pose: FloatArray
    points: FloatArray
    normals: FloatArray
    conflicted: bool


class LocalMap:
    """When and how a matched scan is fused into the local map, and the submaps of sparse
    scans."""

    config: OdometryConfig
    pose: FloatArray
    pyramid: MapPyramid

    def _should_insert(self) -> bool:
        if self._last_inserted is None or self.last_report.rebuilt:
            return True  # a rebuilt map takes the scan at once: it may hold little else
        d = between(self._last_inserted, self.pose)
        c = self.config
        return bool(math.hypot(d[0], d[1]) >= c.insert_distance or abs(d[2]) >= c.insert_angle)

    def _insert(self, pts: FloatArray, normals: FloatArray) -> None:
        c = self.config
        self._turn_submaps()
        centre = self.pyramid.finest.origin + 0.5 * c.map_size
        if np.max(np.abs(self.pose[:2] - centre)) > c.recenter_distance:
            for pyramid in self._maps():
                pyramid.recenter(self.pose[0], self.pose[1])
        if self._last_inserted is None:
            self._first_fused = (self.pose.copy(), pts, self._fill_angle())
        # densified along its surfaces: a scanner's beam pattern fused as measured makes
        # standing still score best
        at_rate = self._at_scanner_rate()
        tolerance = c.densify_tolerance if at_rate else None
        angle = c.dense_straight_angle if at_rate else c.straight_angle
        dense = densify_scan(pts, c.resolution, NORMAL_MAX_GAP, angle, tolerance)
        if dense.shape[0] != pts.shape[0]:
            pts, normals = dense, thinned_normals(dense)
        still = ~self._moving_objects(self.pose, pts)
        conflicted = self.last_report.free_fraction > self.config.recovery_free_fraction
        fusion = Fusion(self.pose.copy(), pts[still], normals[still], conflicted)
        self._fuse(fusion.pose, fusion.points, fusion.normals)
        self._last_inserted = fusion.pose
        self._fusions.append(fusion)

    def _objects(self, pose: FloatArray, pts: FloatArray) -> tuple[NDArray[np.int64], FloatArray]:
        """The objects among a scan's endpoints ``pts`` placed at ``pose``: the runs of them
        standing apart from the walls the map holds (cells above ``wall_logodds``: hit more
        often than seen through, so a person fused once is still no wall), at most
        ``object_size`` long (:func:`compact_runs`: (first, last) rows), and their centres
        (world frame)."""
        c = self.config
        world = transform_points(pose, pts)
        new = ~self.pyramid.finest.above(world, c.wall_logodds)
        return _compact_runs(world, new, c.object_gap, c.object_size)

    def _track_objects(self, stamp: float, pose: FloatArray, pts: FloatArray) -> None:
        """Remember where this scan (matched at ``pose``) saw objects, while the scans come at
        the scanner's rate (:meth:`_at_scanner_rate`)."""
        c = self.config
        if c.object_size <= 0.0 or not self._at_scanner_rate():
            self._object_track.clear()
            return
        if self._object_track and stamp - self._object_track[-1][0] < 0.4 * c.object_lag:
            return  # compared with one a lag before, it needs no finer record
        self._object_track.append((stamp, self._objects(pose, pts)[1]))

    def _moving_objects(self, pose: FloatArray, pts: FloatArray) -> NDArray[np.bool_]:
        """The endpoints of a scan fused at ``pose`` that belong to an object that moved: one
        whose nearest object ``object_lag`` seconds before (:meth:`_track_objects`) lies
        more than ``object_still`` but at most ``object_reach`` metres from it. A person
        walking down a corridor ahead of the robot stands where the map never looked (they
        hid it), so the rule for moving objects in known free space
        (:meth:`_not_in_known_free_space`) never applies: fused at every fusion, they left a
        trail the scans were then matched onto, and the odometry followed them (a SICK at
        10 Hz in the maze with three people walking: lost on four routes of four). A post
        or a box stays where it was, whatever face of it the scan sees; an object seen for
        the first time is fused, unless it is within ``object_near`` of the scanner: a
        person walking up beside the robot (static things that near were seen from
        farther away first)."""
        c = self.config
        moving = np.zeros(pts.shape[0], dtype=bool)
        latest = self._object_track[-1][0] if self._object_track else math.inf
        before = next(
            (seen for stamp, seen in reversed(self._object_track)
             if stamp <= latest - c.object_lag), None,
        )  # fmt: skip
        if before is None:
            return moving
        runs, centres = self._objects(pose, pts)
        near = np.hypot(*(centres - pose[:2]).T) <= c.object_near
        for (first, last), centre, close in zip(runs.tolist(), centres, near, strict=True):
            nearest = float(np.min(np.hypot(*(before - centre).T))) if len(before) else math.inf
            moving[first : last + 1] = c.object_still < nearest and (
                nearest <= c.object_reach or close
            )
        return moving

    def _fill_angle(self) -> float:
        """The ``straight_angle`` a scan is densified with when fused: ``dense_straight_angle``
        at the scanner's rate (:meth:`_at_scanner_rate`), else ``straight_angle`` (the first
        scan: :meth:`_densify_first` adds the rest once the second tells how far apart the
        scans are; fused with straight runs filled at once, a thinned corridor's second scan
        was placed 0.9 m off)."""
        c = self.config
        return c.dense_straight_angle if self._at_scanner_rate() else c.straight_angle

    def _at_scanner_rate(self) -> bool:
        """Something was fused and the scans are not sparse (:meth:`_sparse`,
        :meth:`_sparse_so_far`): the map is many scans of each wall, and a gap that cuts a
        corner is not needed to hold it (``densify_tolerance``). A thinned log's map is a
        few scans, where a door's edge seen by two beams, or a recess's corner, is all that
        fixes a step a metre on (a corridor with doors, a scan per metre: filled only where
        lines continue, the second scan stood still)."""
        return not (self._last_inserted is None or self._as_sparse())

    def _fuse(self, pose: FloatArray, pts: FloatArray, normals: FloatArray) -> None:
        static = self._not_in_known_free_space(pose, pts)
        for pyramid in self._maps():
            pyramid.insert_scan(pose, pts[static], self.config.max_range, normals[static])

    def _rebuild_on_conflict(self, dt: float) -> None:
        """On a scan ``dt`` seconds after the last, no gap (:meth:`_gapless`: not a thinned
        log, whose map is its few last scans), once the typical match (the median of the last
        ``score_window``) leaves more than ``recovery_free_fraction`` of its endpoints in
        known free space, the map matched against is rebuilt from the last
        ``rebuild_scans`` scans fused whose own match did not: the map of an earlier pass,
        drifted, stands where the scans do not, and has for half the window. Each scan is
        fused again as it was then (what it saw in known free space kept out again, now by
        the rebuilt map's rays), and the record of conflicted matches starts afresh."""
        c = self.config
        if not (c.rebuild_scans and self._gapless(dt)):
            return
        if self._typical_free <= c.recovery_free_fraction:
            return
        self.pyramid = self._new_pyramid()
        first = max(len(self._fusions) - c.rebuild_scans, 0)
        for fusion in itertools.islice(self._fusions, first, None):
            if not fusion.conflicted:
                self._fuse(fusion.pose, fusion.points, fusion.normals)
        self._frees.clear()
        self._typical_free = 0.0
        self.num_rebuilds += 1
        self.last_report.rebuilt = True

    def _maps(self) -> list[MapPyramid]:
        """The map matched against and, on sparse scans, the one that will replace it."""
        return [self.pyramid] if self._young is None else [self.pyramid, self._young]

    def _turn_submaps(self) -> None:
        """On sparse scans, once the map holds walls twice, match against the scans of the
        last ``submap_travel`` metres only. Two maps are fused into (Cartographer's
        submaps): the older, matched against, and a younger one begun when the older has
        seen half of ``submap_travel``; once the older has seen all of it, the younger
        replaces it if a step was in doubt and the two maps disagreed on a scan since the
        last turn (:meth:`_maps_disagree`), and is begun anew otherwise. A wrong step puts
        the walls the map already holds a second time, a look-alike's length off, and later
        scans then jump between the two copies (the SICK maze thinned to a scan per metre:
        one wrong turn, then wrong steps on every revisit); a map made only of the scans
        since (or shortly before) it holds one copy.
        Otherwise the older map keeps everything: a thinned log tracked well gains from its
        revisits (freiburg-079 thinned to a scan per metre: RPE over 1 m 4.9 -> 5.6 cm
        when every map was replaced). Off unless ``submap_travel`` is set."""
        c = self.config
        if c.submap_travel <= 0 or self._last_inserted is None:
            return
        d = between(self._last_inserted, self.pose)
        moved = math.hypot(d[0], d[1])
        self._travel = [t + moved for t in self._travel]
        if not self._sparse():
            self._young = None
            return
        if self._young is None and self._travel[0] >= 0.5 * c.submap_travel:
            self._young, self._travel[1] = self._new_pyramid(), 0.0
            return
        grown = self._young is not None and self._travel[1] >= 0.25 * c.submap_travel
        if grown and self._doubts >= c.submap_doubts and not self._conflict:
            self._conflict = self._maps_disagree()
        if self._young is not None and self._travel[0] >= c.submap_travel:
            if self._conflict:
                self.pyramid = self._young
                self.num_submaps += 1
            self._travel = [self._travel[1], 0.0]
            self._young, self._doubts, self._conflict = self._new_pyramid(), 0, False

    def _maps_disagree(self) -> bool:
        """The last scan matched (Gauss-Newton, Eq. 3) on the younger map alone from the pose
        it was given lands farther than ``submap_conflict`` metres (or that at
        ``length_scale`` in heading) from it: the older map holds walls the recent scans put
        elsewhere."""
        c = self.config
        if c.submap_conflict <= 0:
            return True
        if self._young is None or self._matched_levels is None:
            return False
        level_pts, normals, facing = self._matched_levels
        pose, _ = match_scan_to_map(
            self._young, level_pts, self.pose, c.max_iterations, c.step_tolerance,
            c.length_scale, c.degeneracy_ratio, c.subcell_sigma, normals, c.search_prior_weight,
            facing=facing,
        )  # fmt: skip
        d = between(self.pose, pose)
        return bool(
            math.hypot(d[0], d[1]) > c.submap_conflict
            or abs(d[2]) * c.length_scale > c.submap_conflict
        )

    def _new_pyramid(self) -> MapPyramid:
        """An empty local map centred on the pose."""
        c = self.config
        pyramid = MapPyramid(c.resolution, c.map_size, c.levels, c.log_odds, origin=None)
        pyramid.recenter(self.pose[0], self.pose[1])
        return pyramid

    def _densify_first(self, dt: float) -> None:
        """The first scan, fused before anything told how far apart the scans are, gets the
        points densifying adds to those it was fused with (:func:`densify_scan`): with
        ``first_straight_angle`` if the second came after a gap (``gap_time``, a thinned
        log's seconds), else with ``dense_straight_angle``, as every later scan at the
        scanner's rate. Left as dots, the first scan is the whole map for the next ones,
        whose beams land on its dots only when placed back at the start: a SICK in a
        pillared hall, its walls 7-15 m away, stood still while the robot drove 15 m. After
        a gap it also leaves a copy of the finest level with the scan's walls in the cells
        on both sides of the cell edges they run along (``_first_twinned``, on which the
        first match is chosen: :meth:`~bioslam.odometry.choice.MatchChoice._quality_on`)."""
        pose, pts, filled = self._first_fused
        self._first_fused = None
        c = self.config
        angle = c.dense_straight_angle if self._gapless(dt) else c.first_straight_angle
        dense, added = densify_with_mask(pts, c.resolution, NORMAL_MAX_GAP, angle, filled)
        if added.any():
            self._fuse(pose, dense[added], thinned_normals(dense)[added])
        if not self._gapless(dt):
            # every point it was fused with: those added when it was, and these
            whole = densify_scan(pts, c.resolution, NORMAL_MAX_GAP, angle)
            self._first_twinned = copy.deepcopy(self.pyramid.finest)
            self._first_twinned.insert_edge_twins(pose, whole, thinned_normals(whole))

    def _not_in_known_free_space(self, pose: FloatArray, pts: FloatArray) -> NDArray[np.bool_]:
        """Endpoints whose cell and its 8 neighbours several earlier scans saw free are taken
        for moving objects (a person) and not fused: fused, they leave a trail in the map
        that the next scans' points on the same person are pulled towards. (The neighbours
        keep the noisy endpoints in front of a wall, whose own cell the rays have freed.)"""
        world = transform_points(pose, pts)
        return self.pyramid.finest.above_near(world, self.config.free_logodds)
