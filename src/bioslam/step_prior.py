"""How typical a step is: a density of the robot's recent steps between scans (ours).

A log thinned to one scan per metre or per tens of degrees of turn (the public "corrected"
CARMEN logs) has no useful constant-velocity prediction: logged stamps jitter by seconds, and
the robot alternates a metre straight on with turns on the spot. Its steps are nonetheless
very regular: about the thinning distance forward, or about the thinning angle on the spot;
never a metre sideways, a metre backwards, or a standstill. Where the scan cannot tell two
poses apart (a corridor along its axis; the last scan's own sampling pattern, which a pose
next to it reproduces best), this regularity can.

:class:`StepPrior` keeps the last steps the odometry accepted, each in the frame of the scan
before it, and scores a candidate step by a kernel density over them, mixed with a uniform
floor so that a step unlike any recent one (the first turn after a long corridor) costs a
bounded amount, never an infinite one. The density is learnt from the data, so the same prior
holds on a 40 Hz scanner (whose steps are millimetres: any step of tens of centimetres is
unlike them) and on a thinned log (whose steps are a metre or a turn). A few wrong steps
among the recent ones barely change a density, where a nearest-neighbour rule would adopt them.

What no number of steps is needed to know: a wheeled robot (differential drive or car-like, the
robots of nearly every public 2D LiDAR log) drives along its heading, forwards or in reverse,
and between two scans its heading sweeps from the first scan's to the second's, so its
displacement points between the two, or between their opposites when it backs up (a metre on
then a turn, a turn on the spot then a metre on, an arc: all inside that cone). A step that
puts the robot sideways of both cones is unlikely for any such robot; one in the opposite cone
(backing up) less likely than one forward, but possible (:func:`heading_cone_offset`). This
kinematic density takes the place of the uniform floor: a step unlike any recent one still
costs a bounded amount, more if it leaves the cones; and while few steps are known (the floor
raised, or the learned part flat) it is most of the prior. Thinned routes lost within their
first scans (a look-alike two metres sideways after the first turn, or a metre back along a
warehouse aisle, fitting a map of a few scans better than the true step) hold with it. A cone
that charged backing up as much as stepping sideways lost routes that back up
(``bioslam.sim.reversing``); one that did not charge it at all lost the warehouse routes again.
``cone_sigma`` None turns it off for a robot that moves sideways (omnidirectional bases).

What enough steps tell: how far the robot gets and how far it turns between two scans (its
speed and turn rate times their interval, or a log's thinning distance and angle). Once the
prior is no longer young, a step longer than the longest of the recent ones, or turning
farther than the widest of them, costs more the farther it reaches, as one off the cones does:
a look-alike a rack period down an aisle, or a room seen turned round, is then no cheaper
than any other unlikely step.

No file or terminal I/O here.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike

from bioslam.compiled import wrap_scalar
from bioslam.matching.deskew import se2_log

#: :meth:`StepPrior.cost`'s remembered costs at most (a scan asks for a few tens).
_MAX_COSTS = 4096


@dataclass(frozen=True)
class StepPriorConfig:
    """Parameters of :class:`StepPrior`.

    Attributes:
        window: how many recent steps the density is made of.
        sigma_distance, sigma_angle: kernel widths (metres, radians): half the distance and
            angle at which two matches count as distinct places (the wide-basin matcher's
            rival distance and angle), so that the prior separates distinct options and
            leaves the choice within one basin to the scan. ``sigma_angle`` is also how far
            a step may turn beyond the widest recent turn before the kinematic density falls
            (:meth:`StepPrior._within_reach`).
        floor: weight of the uniform component of the mixture; the largest cost is
            ``-log(floor)``.
        floor_steps: with fewer than ``floor_steps / floor`` steps known the floor is
            ``floor_steps / len`` instead: a handful of steps says little about the next
            one. Intel from its first scans: ten turns on the spot, then the first metre on
            (which the scan preferred) lost to a match 0.8 m short, whose walls then pulled
            the pose on every revisit (RPE over 1 m from scans 0-9: median 6.1 cm, at most
            8.3 cm with 2; 5.5 and 6.8 cm with 4; 5.3-5.8 and at most 7.0 cm with 3 to 5).
        max_young_floor: the raised floor is at most this once ``min_steps`` are known,
            so that the learned density weighs at least the rest from then on. Without it
            (1) the prior stayed flat until more than ``floor_steps`` steps were known: down
            a warehouse aisle thinned to a scan per metre, three steps of 1.05 m on, a
            look-alike standing still a rack's period back fitted 0.612 against the true
            step's 0.595 and only the heading cones weighed the two (0.009 apart); the pose
            fell a metre behind, then 2.5 m (SICK, adversarial route, seed 6: ATE 2.8 m;
            0.12 m with 0.5). A lower ``floor_steps`` instead (2) lowered the floor for good:
            a thinned hall route backing up after 23 steps forward was then lost (13 m).
        min_steps: below this many steps the learned density is flat (the cost is the
            kinematic one alone), but for the cost of an echo (:meth:`StepPrior.cost` not
            young), which counts every step known.
        cone_sigma: how far (metres) a step's displacement may leave the cone between its
            start and end headings, or its opposite (:func:`heading_cone_offset`), before the
            kinematic density falls (a Gaussian of the offset); the width of the learned
            kernel, so that a step off the cone by what tells two options apart costs as much
            as one unlike the recent steps by as much; also how far a step may reach beyond
            the longest recent one before it falls (:meth:`StepPrior._within_reach`). None: no
            kinematic density (uniform floor).
        cone_reverse: the kinematic density inside the opposite cone (backing up),
            relative to the forward cone's: a robot does back up, but a metre back along an
            aisle is also where a repetitive place's look-alike lies. The learned density
            weighs the recent steps driven backwards by the same factor
            (:meth:`StepPrior.density`).
        axis_tolerance, axis_coherence: the cones and the learned steps driven backwards are
            taken about the robot's driving axis in the scan's frame, the direction of the
            recent steps' summed displacement (:attr:`StepPrior.axis`), where it departs from
            the scan's forward axis by more than ``axis_tolerance`` radians and the steps
            agree on it (the sum at least ``axis_coherence`` of their summed lengths, and
            longer than ``sigma_distance``), counting the steps that turned less than
            ``sigma_angle`` (turning on the spot, a scanner off the robot's axis of rotation
            moves sideways: intel's first ten turns, 0.25 m at -110°): a
            scanner mounted facing backwards or sideways, or a whole log driven in reverse,
            otherwise pays the backing-up factor for every true step (intel played
            backwards, a scan per metre: 317 of 909 steps off by more than 0.2 m or 5°, the
            run lost; as logged, 6). Within the tolerance the axis stays the forward one,
            which a robot weaving along a corridor leaves a few degrees either way.
        cone_floor: the kinematic density's least value (a step far off the cones): its
            cost is at most ``-log(cone_floor)`` more than a uniform floor's, so that after an
            odometry error the true pose, whose step leaves the cones, can still win on the
            scan's evidence.
    """

    window: int = 100
    sigma_distance: float = 0.25
    sigma_angle: float = math.radians(10.0)
    floor: float = 0.05
    floor_steps: float = 4.0
    max_young_floor: float = 0.5
    min_steps: int = 3
    cone_sigma: float | None = 0.25
    cone_reverse: float = 0.3
    cone_floor: float = 0.1
    axis_tolerance: float = math.radians(30.0)
    axis_coherence: float = 0.5

    def __post_init__(self) -> None:
        if self.window < 1 or self.min_steps < 1:
            raise ValueError(
                f"window and min_steps must be positive, got {self.window}, {self.min_steps}"
            )
        if not (self.sigma_distance > 0 and self.sigma_angle > 0):
            raise ValueError(
                f"kernel widths must be positive, got {self.sigma_distance}, {self.sigma_angle}"
            )
        if not 0.0 < self.floor <= 1.0:
            raise ValueError(f"floor must be in (0, 1], got {self.floor}")
        if not 0.0 < self.max_young_floor <= 1.0:
            raise ValueError(f"max_young_floor must be in (0, 1], got {self.max_young_floor}")
        if self.floor_steps < 0:
            raise ValueError(f"floor_steps must be non-negative, got {self.floor_steps}")
        if self.cone_sigma is not None and not self.cone_sigma > 0:
            raise ValueError(f"cone_sigma must be None or positive, got {self.cone_sigma}")
        if not 0.0 < self.cone_floor <= 1.0:
            raise ValueError(f"cone_floor must be in (0, 1], got {self.cone_floor}")
        if not 0.0 <= self.cone_reverse <= 1.0:
            raise ValueError(f"cone_reverse must be in [0, 1], got {self.cone_reverse}")


def heading_cone_offset(step: ArrayLike, reverse: bool = False) -> float:
    """How far (metres) the displacement of ``step`` (dx, dy, dθ in the frame of its start)
    lies outside the cone of directions between its start and end headings (0 and dθ), or
    with ``reverse`` the opposite cone (a robot backing up): 0 inside it, else the distance
    to the nearer edge ray beside it, the whole displacement behind both. A robot that
    drives along its heading while turning one way moves inside one of them."""
    dx, dy, turn = np.asarray(step, dtype=np.float64).reshape(3).tolist()
    return _forward_cone_offset(-dx, -dy, turn) if reverse else _forward_cone_offset(dx, dy, turn)


def arc_length(step: ArrayLike) -> float:
    """The length of the circular arc, tangent to the start heading, that a step (dx, dy,
    dθ) follows driven at a constant speed and turn rate (the translation of its constant
    body twist, :func:`bioslam.matching.deskew.se2_log`), forwards or backwards: the path a
    wheeled robot covers with that step."""
    vx, vy, _ = se2_log(step)
    return math.hypot(vx, vy)


def driven_backwards(steps: np.ndarray, axis: float = 0.0) -> np.ndarray:
    """Each step (dx, dy, dθ; (..., 3)) as the robot would take it backing up: the
    unicycle's motion with both its speed and its turn rate negated (the path mirrored
    behind it), about the driving ``axis`` (radians in the scan's frame, :attr:`StepPrior.axis`):
    (-dx, dy, -dθ) for a scanner facing forward or backwards."""
    steps = np.asarray(steps, dtype=np.float64)
    c, s = math.cos(2.0 * axis), math.sin(2.0 * axis)
    out = np.empty_like(steps)
    # the reflection across the line square to the axis
    out[..., 0] = -c * steps[..., 0] - s * steps[..., 1]
    out[..., 1] = -s * steps[..., 0] + c * steps[..., 1]
    out[..., 2] = -steps[..., 2]
    return out


def along_axis(step: ArrayLike, axis: float) -> np.ndarray:
    """``step`` (dx, dy, dθ), given in the robot's driving frame, in the scan's frame whose
    forward axis is turned by ``-axis`` from it: its displacement turned by ``axis``."""
    dx, dy, turn = np.asarray(step, dtype=np.float64).reshape(3).tolist()
    c, s = math.cos(axis), math.sin(axis)
    return np.array([c * dx - s * dy, s * dx + c * dy, turn])


def _forward_cone_offset(dx: float, dy: float, turn: float) -> float:
    """The distance of (dx, dy) from the cone of directions between 0 and ``turn``: 0 inside,
    to the nearer edge ray beside it, the whole displacement behind both."""
    direction = math.atan2(dy, dx)
    low, high = min(0.0, turn), max(0.0, turn)
    if low <= direction <= high:
        return 0.0
    offset = math.inf
    for edge in (low, high):
        ux, uy = math.cos(edge), math.sin(edge)
        ahead = dx * ux + dy * uy >= 0.0
        offset = min(offset, abs(dx * uy - dy * ux) if ahead else math.hypot(dx, dy))
    return offset


class StepPrior:
    """A kernel density of the last accepted steps ``(dx, dy, dtheta)`` (previous scan's
    frame), as a cost ``-log`` of a mixture with a uniform floor."""

    def __init__(self, config: StepPriorConfig | None = None) -> None:
        self.config = config or StepPriorConfig()
        self._steps: deque[tuple[float, float, float]] = deque(maxlen=self.config.window)
        # the recent steps, (n, 3), and with the same driven backwards, (2, n, 3), made once
        # per new step
        self._recent: np.ndarray | None = None
        self._array: np.ndarray | None = None
        self._axis: float | None = None  # :attr:`axis`, made once per new step
        self._extent: tuple[float, float] | None = None
        # each recent step's :func:`arc_length`, made once as it comes (all of them anew
        # for every new step cost a thinned log's scan a twentieth)
        self._arcs: deque[float] = deque(maxlen=self.config.window)
        self._lengths: np.ndarray | None = None  # :meth:`_path_lengths`
        # :meth:`thinning_extent`, and whether it was read since the last step
        self._thinning: tuple[float, float] | None = None
        self._thinning_read = False
        # the kernel between every two recent steps, grown a row and a column a step, for
        # :meth:`modes` (all of them anew cost a thinned log's scan 0.25 ms)
        self._pairs = np.zeros((0, 0))
        # :meth:`cost` per (step, young) since the last step: the sparse chooser and the
        # turned windows' checks ask again for the same matches
        self._costs: dict[tuple[float, float, float, bool], float] = {}

    def __len__(self) -> int:
        return len(self._steps)

    @property
    def flat(self) -> bool:
        """The learned density says nothing yet (:meth:`cost` with ``young`` is the
        kinematic cost alone): too few steps are known to tell a typical one from any
        other."""
        n = len(self._steps)
        return n < self.config.min_steps or self._young_floor(n) >= 1.0

    def _young_floor(self, n: int) -> float:
        """The uniform (or kinematic) component's weight with ``n`` steps known: ``floor``,
        raised to ``floor_steps / n`` while few are known, but at most ``max_young_floor``
        (or ``floor`` if that is higher)."""
        c = self.config
        return max(c.floor, min(c.floor_steps / n, c.max_young_floor))

    def add(self, step: ArrayLike) -> None:
        """Remember an accepted step (metres, metres, radians)."""
        dx, dy, dth = (float(v) for v in np.asarray(step, dtype=np.float64).reshape(3))
        full = len(self._steps) == self._steps.maxlen
        self._steps.append((dx, dy, dth))
        self._arcs.append(arc_length((dx, dy, dth)))
        self._recent = None
        self._array = None
        self._axis = None
        self._extent = None
        self._lengths = None
        self._thinning_read = False
        self._costs.clear()
        c = self.config
        kept = self._pairs[1:, 1:] if full else self._pairs
        self._pairs = _grown_pairs(kept, self._history(), c.sigma_distance, c.sigma_angle)

    @property
    def axis(self) -> float:
        """The robot's driving axis in the scan's frame, radians: the direction of the recent
        steps' summed displacement (of those turning less than ``sigma_angle``) where it
        departs from the forward axis (0) by more than ``axis_tolerance``, is at least
        ``axis_coherence`` of their summed lengths and longer than ``sigma_distance``; else
        0 (:class:`StepPriorConfig`)."""
        if self._axis is None:
            self._axis = self._read_axis()
        return self._axis

    def _read_axis(self) -> float:
        """:attr:`axis`, computed."""
        c = self.config
        if len(self._steps) < c.min_steps:
            return 0.0
        steps = self._history()
        moves = steps[np.abs(steps[:, 2]) < c.sigma_angle, :2]
        total = moves.sum(axis=0)
        direction = math.atan2(total[1], total[0])
        reach = math.hypot(*total)
        coherent = reach >= max(c.axis_coherence * np.hypot(*moves.T).sum(), c.sigma_distance)
        return direction if coherent and abs(direction) > c.axis_tolerance else 0.0

    def density(self, step: ArrayLike) -> float:
        """The mean Gaussian kernel of ``step`` against the recent steps, or ``cone_reverse``
        times that against them driven backwards if larger (:meth:`_mean_kernel`), in [0, 1]
        (1: the step equals every recent one); 1 while fewer than ``min_steps`` are known."""
        if len(self._steps) < self.config.min_steps:
            return 1.0
        return self._mean_kernel(step)

    def _mean_kernel(self, step: ArrayLike) -> float:
        """The learned density of ``step``: its mean kernel against the recent steps, or
        ``cone_reverse`` times that against the same steps driven backwards
        (:func:`driven_backwards`), whichever is larger. A robot that drove a metre on at a
        time can back up a metre at a time, and its first steps back are unlike any it
        took: charged as such (the floor's cost), a thinned warehouse route backing up
        along an aisle took a look-alike a metre ahead at every step back, though the scan
        fitted the true step far better (0.746 against 0.579), and was lost (SICK, 24
        simulated routes backing up every 45 s, thinned to a scan per metre: 8 lost, 2
        with the steps driven backwards)."""
        c = self.config
        s = np.asarray(step, dtype=np.float64).reshape(3)
        kernels = _kernels(self._histories(), s, c.sigma_distance, c.sigma_angle)
        ahead, back = np.mean(kernels, axis=-1).tolist()
        return max(ahead, c.cone_reverse * back)

    def _histories(self) -> np.ndarray:
        """The recent steps and the same :func:`driven_backwards`, (2, n, 3)."""
        if self._array is None:
            steps = self._history()
            self._array = np.stack([steps, driven_backwards(steps, self.axis)])
        return self._array

    def _history(self) -> np.ndarray:
        """The recent steps as an (n, 3) array."""
        if self._recent is None:
            self._recent = np.array(self._steps).reshape(-1, 3)
        return self._recent

    def cost(self, step: ArrayLike, young: bool = True) -> float:
        """``-log((1 - f) * density + f * kinematic)`` with ``f`` the floor and
        ``kinematic`` :meth:`kinematic`: 0 for a step like all recent ones (and inside its
        heading cone), at most ``-log(f * cone_floor)`` for a step unlike any. ``young``:
        the floor is raised while few steps are known (``floor_steps``), and is the whole
        prior while the learned density is :attr:`flat`; not young (the cost of an echo),
        every step known counts against a uniform floor: a step the odometry must not take
        however few it knows (onto the pose where a scan was just fused, whose beam pattern
        a sparse map echoes)."""
        dx, dy, turn = np.asarray(step, dtype=np.float64).reshape(3).tolist()
        key = (dx, dy, turn, young)
        known = self._costs.get(key)
        if known is None:
            if len(self._costs) >= _MAX_COSTS:  # a run that stays dense adds no step
                self._costs.clear()
            known = self._costs[key] = self._cost(step, young)
        return known

    def _cost(self, step: ArrayLike, young: bool) -> float:
        """:meth:`cost`, computed."""
        if young:
            kinematic = self.kinematic(step)
            if self.flat:
                return -math.log(kinematic)
            f = self._young_floor(len(self._steps))
        else:
            if not self._steps:
                return 0.0
            kinematic, f = 1.0, self.config.floor
        return -math.log((1.0 - f) * self._mean_kernel(step) + f * kinematic)

    def kinematic(self, step: ArrayLike) -> float:
        """The kinematic density of ``step``, in [``cone_floor``, 1]: 1 inside its heading
        cone (:func:`heading_cone_offset`), ``cone_reverse`` of that inside the opposite
        one, each falling as a Gaussian of ``cone_sigma`` outside, and beyond the reach of
        the recent steps (:meth:`_within_reach`); 1 for every step without ``cone_sigma``."""
        c = self.config
        if c.cone_sigma is None:
            return 1.0
        dx, dy, turn = along_axis(step, -self.axis).tolist()
        forward = _forward_cone_offset(dx, dy, turn) / c.cone_sigma
        reverse = _forward_cone_offset(-dx, -dy, turn) / c.cone_sigma
        inside = max(
            math.exp(-0.5 * forward * forward), c.cone_reverse * math.exp(-0.5 * reverse * reverse)
        )
        return c.cone_floor + (1.0 - c.cone_floor) * inside * self._within_reach(dx, dy, turn)

    def _within_reach(self, dx: float, dy: float, turn: float) -> float:
        """1 for a step no longer than the longest of the recent steps and turning no
        farther than the widest of them, falling as a Gaussian of ``cone_sigma`` for the
        displacement beyond the one and of ``sigma_angle`` for the turn beyond the other,
        once the prior is no longer young (``floor`` no longer raised, :meth:`_young_floor`);
        1 before. Between two scans a robot moves at most its speed, and turns at most its
        turn rate, times their interval, or a log's thinning distance and angle, and the
        longest and widest of its last steps are what those have been. A match 3.4 m on
        down an aisle, where no step in 95 had been longer than 1.1 m, fitted 0.87 against
        the true step's 0.78 and cost only the floor's 0.02 more than it (simulated
        warehouse, URG-04LX, thinned to a scan per metre, adversarial route, seed 5: ATE
        1.58 m -> 5.8 cm). A 240° URG-04LX (5.6 m) thinned to a scan per metre or 34° of
        turn, turning into a room it had not seen, fitted 0.27 where it was and 0.73 turned
        round by 147°, looking back down the corridor it came from (simulated office, tour,
        seed 5: ATE 4.9 m -> 9.6 cm). Young, the bound learnt standstills: intel starts
        with ten turns on the spot, and its first metre on lost (RPE over 1 m from scans
        0-9, median 4.8 -> 15 cm)."""
        n = len(self._steps)
        c = self.config
        if n == 0 or self._young_floor(n) > c.floor:
            return 1.0
        longest, widest = self._extent_of_steps()
        beyond = max(0.0, math.hypot(dx, dy) - longest) / c.cone_sigma
        turned = max(0.0, abs(turn) - widest) / c.sigma_angle
        return math.exp(-0.5 * (beyond * beyond + turned * turned))

    def _extent_of_steps(self) -> tuple[float, float]:
        """The longest displacement (metres) and the widest turn (radians) among the recent
        steps."""
        if self._extent is None:
            steps = self._history()
            self._extent = (
                float(np.max(np.hypot(steps[:, 0], steps[:, 1]))),
                float(np.max(np.abs(steps[:, 2]))),
            )
        return self._extent

    def turning_length(self, turn: float) -> float | None:
        """The median path length (:func:`arc_length`) of the recent steps that turned at
        least half as far as ``turn`` (radians) either way: how far the robot goes while it
        turns that much (about nothing for one that turns on the spot, a metre for one
        thinned to a scan per metre that turns while it drives). None while no such step is
        known."""
        if not self._steps:
            return None
        turning = np.abs(self._history()[:, 2]) >= 0.5 * abs(turn)
        if not turning.any():
            return None
        return float(np.median(self._path_lengths()[turning]))

    def length_cost(self, step: ArrayLike) -> float:
        """``-log`` of how likely a step of that path length (:func:`arc_length`) and turn
        ends where ``step`` does on a log thinned by distance or angle, mixed with the
        uniform ``floor``. Such a log ends every step at the first of the two: a metre on
        however little it turned, or 0.6 rad round however little it went; so a step
        shorter than the recent nearly straight steps (turning less than ``sigma_angle``:
        their median length, :meth:`thinning_extent`) that turned less than the recent
        steps ended short of that length did (the least of their turns) reached neither.
        Its density is ``1 - (1 - exp(-s²/2)) (1 - exp(-u²/2))``, with ``s`` the step's
        length short of the straight steps' in ``sigma_distance`` and ``u`` its turn short
        of the short steps' in ``sigma_angle``: 1 (cost 0) where it reached either. 0 while
        the learned density is :attr:`flat` or the recent steps show no such rule (too few
        straight steps, none ended short: a scanner at its rate)."""
        extent = self.thinning_extent() if not self.flat else None
        if extent is None:
            return 0.0
        c = self.config
        distance, angle = extent
        turn = abs(float(np.asarray(step, dtype=np.float64).reshape(3)[2]))
        short = max(0.0, distance - arc_length(step)) / c.sigma_distance
        less = max(0.0, angle - turn) / c.sigma_angle
        neither = (1.0 - math.exp(-0.5 * short * short)) * (1.0 - math.exp(-0.5 * less * less))
        return -math.log((1.0 - c.floor) * (1.0 - neither) + c.floor)

    def thinning_extent(self) -> tuple[float, float] | None:
        """The distance and angle at which the recent steps ended, as a log thinned by
        distance or angle ends them (:meth:`length_cost`): the median path length of the
        steps that turned less than ``sigma_angle``, and the least turn of the steps
        shorter than that by more than two ``sigma_distance``. None with fewer than
        ``min_steps`` such straight steps or no such short one. Made once per new step."""
        if not self._thinning_read:
            self._thinning, self._thinning_read = self._read_thinning(), True
        return self._thinning

    def _read_thinning(self) -> tuple[float, float] | None:
        """:meth:`thinning_extent`, computed."""
        c = self.config
        lengths, turns = self._path_lengths(), np.abs(self._history()[:, 2])
        straight = turns < c.sigma_angle
        if np.count_nonzero(straight) < c.min_steps:
            return None
        distance = float(np.median(lengths[straight]))
        short = lengths < distance - 2.0 * c.sigma_distance
        if not short.any():
            return None
        return distance, float(np.min(turns[short]))

    def _path_lengths(self) -> np.ndarray:
        """The recent steps' :func:`arc_length`, (n,)."""
        if self._lengths is None:
            self._lengths = np.array(self._arcs)
        return self._lengths

    def modes(self, count: int) -> list[np.ndarray]:
        """Up to ``count`` typical steps: the recent steps of highest density, each more
        than twice the kernel widths (in distance or in angle) from those before it. Where
        the prediction cannot be trusted, each is a start for the match as good as any
        motion hypothesis: a thinned log's robot goes a metre on, turns either way on the
        spot or along an arc, and which one it did last says little about the next."""
        if len(self._steps) < self.config.min_steps or count < 1:
            return []
        c = self.config
        chosen = _typical_steps(
            self._history(), self._pairs, c.sigma_distance, c.sigma_angle, count
        )
        return [step.copy() for step in chosen]


@numba.njit(cache=True)
def _pair_kernel(a: np.ndarray, b: np.ndarray, sigma_distance: float, sigma_angle: float):
    """The Gaussian kernel between steps ``a`` and ``b`` (x, y, θ)."""
    turn = wrap_scalar(a[2] - b[2])
    dx, dy = a[0] - b[0], a[1] - b[1]
    e = (dx * dx + dy * dy) / sigma_distance**2 + turn * turn / sigma_angle**2
    return math.exp(-0.5 * e)


@numba.njit(cache=True)
def _kernels(histories: np.ndarray, step: np.ndarray, sigma_distance: float, sigma_angle: float):
    """The kernel between ``step`` and each of ``histories`` (k, n, 3): (k, n). Compiled: as
    NumPy array operations on a hundred steps, the step prior's cost was a twentieth of a
    thinned log's scan."""
    out = np.empty(histories.shape[:2])
    for i in range(histories.shape[0]):
        for k in range(histories.shape[1]):
            out[i, k] = _pair_kernel(histories[i, k], step, sigma_distance, sigma_angle)
    return out


@numba.njit(cache=True)
def _grown_pairs(kept: np.ndarray, steps: np.ndarray, sigma_distance: float, sigma_angle: float):
    """The pairwise kernels of ``steps`` (n, 3) from those of all but the last (``kept``,
    (n - 1, n - 1)): a row and a column more."""
    n = steps.shape[0]
    out = np.empty((n, n))
    out[: n - 1, : n - 1] = kept
    for j in range(n):
        out[n - 1, j] = _pair_kernel(steps[n - 1], steps[j], sigma_distance, sigma_angle)
        # both ways: the wrap of a turn is not odd to the bit, and the densities summed from
        # these rows are the ones the vectorised form gave
        out[j, n - 1] = _pair_kernel(steps[j], steps[n - 1], sigma_distance, sigma_angle)
    return out


@numba.njit(cache=True)
def _typical_steps(
    steps: np.ndarray, pairs: np.ndarray, sigma_distance: float, sigma_angle: float, count: int
):
    """:meth:`StepPrior.modes` on ``steps`` (n, 3) and their pairwise kernels ``pairs``
    (n, n): up to ``count`` rows, densest first, each beyond twice a kernel width of every
    one before it. In loops: the pairwise arrays of the vectorised form cost 0.8 ms a scan
    on intel (a window of 100 steps), a tenth of the odometry's whole step there."""
    n = steps.shape[0]
    density = np.empty(n)
    for i in range(n):
        total = 0.0
        for j in range(n):
            total += pairs[i, j]
        density[i] = total
    order = np.argsort(-density, kind="mergesort")  # stable: the older of equals first
    open_ = np.ones(n, dtype=np.bool_)  # far from every step chosen so far
    chosen = []
    for i in order:
        if len(chosen) == count:
            break
        if not open_[i]:
            continue
        chosen.append(steps[i])
        for k in range(n):
            dx, dy = steps[k, 0] - steps[i, 0], steps[k, 1] - steps[i, 1]
            turn = wrap_scalar(steps[k, 2] - steps[i, 2])
            far = math.hypot(dx, dy) > 2 * sigma_distance or abs(turn) > 2 * sigma_angle
            open_[k] = open_[k] and far
    return chosen
