"""The robot's own body in its scans: beams that a mast, a bumper or a cable always block.

A scanner mounted among the robot's parts (a 360° scanner between the posts of a TurtleBot's
deck, a 270° one behind a bumper) returns, in a few directions, the same short range in every
scan. Those endpoints move with the robot: the odometry, matching them against a map in which
they were fused along the whole path, is pulled towards standing still, and the views carry
them as a wall that is everywhere (a simulated RPLIDAR with four posts at 0.22 m: odometry
1.55 -> 3.75 cm). Which directions are blocked differs from robot to robot, so they are
learned, as ``laser_filters`` would be told them: a direction whose range has stayed the same
(within the scanner's noise) and short while the robot turned a quarter of a turn left and a
quarter of a turn right is blocked by the robot itself. No part of the world does that: a wall
beside a corridor keeps its range while the robot drives straight on, but not while it turns;
the corner a robot turns round keeps its range and bearing through the turn (the maze's
UTM-30LX weaving route: 0.96 m through a quarter turn left), but not through the turn back;
and the ends of two spins either side of a straight run along a wall are not quarter turns
(the same route: 54° right, 9 s along a corridor, 57° left, a wall 0.64 m away behind on
the right all along, learned as the body when an eighth of a turn each way sufficed). A
direction blocked, and then seen at another range for a while, is free again (a person
walking alongside through both turns).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numba
import numpy as np
from numpy.typing import NDArray

from bioslam.scan import LaserScan

FloatArray = NDArray[np.float64]

#: directions are told apart to a degree (beams of a finer scanner share one)
BIN = math.radians(1.0)
BINS = round(2.0 * math.pi / BIN)
#: a range "the same" as the mean a direction has held within this, metres, plus
#: ``RELATIVE`` of it: a few standard deviations of a scanner's noise
TOLERANCE = 0.05
RELATIVE = 0.02
#: scans a direction must hold its range through the turns (the body is in every scan; on a
#: thinned log, a few scans far apart turned both ways round a direction that happened to
#: read alike: a lost odometry on the maze's RPLIDAR every 20th scan blocked 7-14)
MIN_SCANS = 50
#: scans a blocked direction must read otherwise before it counts as free again
RELEASE = 20
#: at most this share of the directions is the body's: more holding their ranges through a
#: turn say the turn was not made (an odometry that jumped, not a robot that turned)
MAX_SHARE = 0.25


class BodyHits:
    """The directions of a scanner that the robot's own body blocks, learned as it turns
    (module docstring). ``reach``: only a range shorter than this can be the body (metres;
    0 learns none); ``turn``: how far the robot must turn (radians), half of it each way, with
    a direction's range unchanged."""

    def __init__(self, reach: float = 1.0, turn: float = math.pi) -> None:
        self.reach = reach
        self.turn = turn
        self._held = np.full(BINS, np.nan)  # the mean range each direction has held
        self._count = np.zeros(BINS)  # over this many scans
        self._low = np.zeros(BINS)  # the headings turned through while it held it
        self._high = np.zeros(BINS)
        self._left = np.zeros(BINS)  # the largest turn left and right within them
        self._right = np.zeros(BINS)
        self.blocked = np.zeros(BINS, dtype=bool)
        self._away = np.zeros(BINS, dtype=np.int64)
        self._angles: FloatArray | None = None
        self._bins = np.zeros(0, dtype=np.int64)

    def _bins_of(self, angles: FloatArray) -> NDArray[np.int64]:
        if angles is not self._angles:  # (one array for every scan of a scanner)
            self._angles = angles
            self._bins = np.floor(np.mod(angles, 2.0 * math.pi) / BIN).astype(np.int64) % BINS
        return self._bins

    def without(self, scan: LaserScan) -> LaserScan:
        """``scan`` with the beams of the blocked directions as no return (the same object
        when none is blocked)."""
        if self.reach <= 0.0 or not self.blocked.any():
            return scan
        hidden = self.blocked[self._bins_of(scan.angles)]
        if not hidden.any():
            return scan
        ranges = np.array(scan.ranges, copy=True)
        ranges[hidden] = np.nan
        return replace(scan, ranges=ranges)

    def observe(self, scan: LaserScan, heading: float) -> None:
        """Learn from ``scan`` (as measured, body hits included) taken at the unwrapped
        ``heading`` (radians, the odometry's, turns counted)."""
        if self.reach <= 0.0:
            return
        near = _nearest_per_direction(
            np.asarray(scan.ranges), scan.valid_mask, self._bins_of(scan.angles), self.reach
        )
        turned = _hold(
            near, heading, self._held, self._count, self._low, self._high, self._left,
            self._right, self._away, self.blocked, 0.5 * self.turn,
        )  # fmt: skip
        if np.count_nonzero(self.blocked | turned) <= MAX_SHARE * BINS:
            self.blocked |= turned


@numba.njit(cache=True)
def _nearest_per_direction(ranges, valid, bins, reach):
    """The shortest valid range of each direction's beams, NaN where none is under ``reach``."""
    near = np.full(BINS, np.inf)
    for k in range(ranges.shape[0]):
        if valid[k] and ranges[k] < near[bins[k]]:
            near[bins[k]] = ranges[k]
    for b in range(BINS):
        if not near[b] < reach:
            near[b] = np.nan
    return near


@numba.njit(cache=True)
def _hold(near, heading, held, count, low, high, left, right, away, blocked, half_turn):
    """One scan's update of each direction's held range (``near``, NaN for none): its mean,
    the scans and the headings it held it through, the turns left and right within them;
    a blocked direction that reads otherwise long enough is freed. Returns the directions
    that held theirs through ``half_turn`` each way (which :class:`BodyHits` then blocks
    unless too many did)."""
    turned = np.zeros(BINS, dtype=np.bool_)
    for b in range(BINS):
        same = abs(near[b] - held[b]) <= TOLERANCE + RELATIVE * held[b]  # NaN: False
        if same:
            count[b] += 1.0
            held[b] += (near[b] - held[b]) / count[b]
            left[b] = max(left[b], heading - low[b])
            right[b] = max(right[b], high[b] - heading)
            low[b] = min(low[b], heading)
            high[b] = max(high[b], heading)
            away[b] = 0
            turned[b] = count[b] >= MIN_SCANS and min(left[b], right[b]) >= half_turn
        else:
            # a direction whose range changed starts holding the new one from this heading
            count[b] = 1.0
            held[b] = near[b]
            left[b] = right[b] = 0.0
            low[b] = high[b] = heading
            if blocked[b]:
                away[b] += 1
                blocked[b] = away[b] < RELEASE
    return turned
