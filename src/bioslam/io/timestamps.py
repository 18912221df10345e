"""Checking a log's time stamps as a whole, before any scan is used.

A reader that trusts each stamp on its own loses whole logs to one defect: a scan stamped an
hour late makes every later scan look out of order; stamps printed with six significant digits
(``1.13486e+09``) give hundreds of scans one stamp; a log written with a reset clock, negated or
concatenated with itself decreases somewhere. :func:`plan_stamps` looks at all the stamps of a
log's scan records (file order) and decides, once, which stamp each record gets:

* **log stamps**: the records whose stamps increase with the file (the longest strictly
  increasing subsequence), plus, for a reader with a reorder window (none by default), records a
  little out of order (put back in order by the reader) keep their stamps exactly. Records left
  over (non-finite, out of order, a repeated stamp) are *repaired*: interpolated by record index
  between their nearest kept neighbours. Used when at least :data:`MIN_USABLE_SHARE` of the
  records keep their stamps, the bad ones are isolated (no run longer than
  :data:`MAX_BAD_RUN_SHARE` of the log, and none their neighbours leave no room for: a clock
  set back, :func:`_squeezed_run`) and the median interval of the kept stamps is one a scanner
  can have.
* **record order**: otherwise the stamps cannot be used as they are, and record ``k`` is
  stamped ``t0 + k * period``, with the period the log declares (a sensor's scan time) or, failing
  that, the one its stamps imply (the span of the ordered records over their count, or the
  median step between consecutive stamps). Where the steps between stamps still measure time
  (stamps counting down, a log concatenated with itself) those steps are kept instead of the
  period (:func:`record_order_steps`).

A clean log keeps every stamp bit for bit.
"""

from __future__ import annotations

from bisect import bisect_left
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Share of the records whose stamps must be usable as they are for the log's stamps to be kept.
MIN_USABLE_SHARE = 0.5
#: Longest run of consecutive bad stamps that is repaired (share of the records; at least 2):
#: a longer one (half a log concatenated with itself) leaves no neighbours to interpolate from.
MAX_BAD_RUN_SHARE = 0.1
#: A first or last few records (at most this share, or 2) are stray when a jump of this many
#: median periods separates them from the rest.
STRAY_JUMP_PERIODS = 100.0
MAX_STRAY_SHARE = 0.01
#: Scan periods a 2D LiDAR can have (s): outside, the stamps are in another unit or meaningless.
PLAUSIBLE_PERIOD_S = (1e-3, 60.0)
#: A step between stamps kept in record order lies within this factor of the period.
STEP_BAND = 20.0
#: Fewest records a stretch stamped by a clock set back holds (:func:`_squeezed_run`).
MIN_SQUEEZED_RUN = 3
#: Period assumed when neither the log nor its stamps give one (10 Hz, the commonest rate).
DEFAULT_PERIOD_S = 0.1

LOG_STAMPS = "log stamps"
RECORD_ORDER = "record order"


@dataclass(frozen=True)
class TimePlan:
    """The stamp each scan record of a log gets (see the module docstring).

    Attributes:
        stamps: one per scan record, in file order (strictly increasing except for records
            kept a little out of order, which the reader puts back in order).
        source: :data:`LOG_STAMPS` or :data:`RECORD_ORDER`.
        repaired: records whose stamp was replaced (log stamps) or all records (record order).
        period_s: the record-order period, or the median interval of the kept stamps.
        reason: why the stamps were repaired or not used; "" for a clean log.
        alternative: the name of the record's second stamps when those were used because the
            main ones were unusable (e.g. CARMEN's ``logger_timestamp``), else "".
    """

    stamps: NDArray[np.float64]
    source: str
    repaired: int
    period_s: float
    reason: str = ""
    alternative: str = ""

    def describe(self) -> str:
        """One line for notes and summaries: ``log stamps``, ``log stamps (3 repaired: ...)``
        or ``record order at 10 Hz (reason)``."""
        if self.source == RECORD_ORDER:
            return f"{RECORD_ORDER} at {1.0 / self.period_s:.4g} Hz ({self.reason})"
        if self.alternative:
            return f"{LOG_STAMPS}: {self.alternative} ({self.reason})"
        if self.repaired:
            return f"{LOG_STAMPS} ({self.repaired} repaired from their neighbours: {self.reason})"
        return LOG_STAMPS


def longest_increasing(values: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Mask of a longest strictly increasing subsequence of the finite ``values``.

    Patience sorting, O(n log n). Among equally long ones the one ending with the latest
    records is kept, so a single stamp far ahead of its neighbours is the one left out.
    """
    tails: list[float] = []
    tail_index: list[int] = []
    previous = np.full(values.size, -1, dtype=np.int64)
    for i, v in enumerate(values.tolist()):
        if not np.isfinite(v):
            continue
        pos = bisect_left(tails, v)
        if pos == len(tails):
            tails.append(v)
            tail_index.append(i)
        else:
            tails[pos] = v
            tail_index[pos] = i
        previous[i] = tail_index[pos - 1] if pos else -1
    keep = np.zeros(values.size, dtype=bool)
    i = tail_index[-1] if tail_index else -1
    while i >= 0:
        keep[i] = True
        i = int(previous[i])
    return keep


def _drop_stray_ends(
    stamps: NDArray[np.float64], anchors: NDArray[np.bool_], period: float, window: float
) -> NDArray[np.bool_]:
    """``anchors`` without a few first or last records cut off from the rest by a jump of more
    than :data:`STRAY_JUMP_PERIODS` periods: a first scan stamped 0 or a last one an hour
    late is in time order, yet as wrong as a spike in the middle."""
    idx = np.flatnonzero(anchors)
    if idx.size < 4 or not np.isfinite(period):
        return anchors
    jump = max(window, STRAY_JUMP_PERIODS * period)
    steps = np.diff(stamps[idx])
    few = max(2, int(MAX_STRAY_SHARE * idx.size))
    out = anchors.copy()
    big = np.flatnonzero(steps > jump)
    if big.size and big[0] + 1 <= few:  # the first big step leaves few records before it
        out[idx[: big[0] + 1]] = False
    if big.size and idx.size - 1 - big[-1] <= few:  # the last one leaves few after it
        out[idx[big[-1] + 1 :]] = False
    return out if out.sum() >= 2 else anchors


def _tolerated(
    stamps: NDArray[np.float64], anchors: NDArray[np.bool_], window: float, period: float
) -> NDArray[np.bool_]:
    """Records outside the increasing subsequence the reader can still put back in order: a
    finite stamp within ``window`` of its anchored neighbours (one period per record beyond
    the first or last anchor), repeating no anchored stamp."""
    idx = np.flatnonzero(anchors)
    out = np.zeros(stamps.size, dtype=bool)
    if idx.size == 0:
        return out
    anchored = set(stamps[idx].tolist())
    candidates = np.flatnonzero(~anchors & np.isfinite(stamps))
    pos = np.searchsorted(idx, candidates)
    step = period if np.isfinite(period) else 0.0
    for i, p in zip(candidates.tolist(), pos.tolist(), strict=True):
        lo = stamps[idx[p - 1]] if p > 0 else stamps[idx[0]] - step * (idx[0] - i)
        hi = stamps[idx[p]] if p < idx.size else stamps[idx[-1]] + step * (i - idx[-1])
        t = stamps[i]
        out[i] = lo - window <= t <= hi + window and t not in anchored
    return out


def _anchor_period(stamps: NDArray[np.float64], idx: NDArray[np.int64]) -> float:
    """Median seconds per record between consecutive anchors (NaN if fewer than two)."""
    if idx.size < 2:
        return float("nan")
    return float(np.median(np.diff(stamps[idx]) / np.diff(idx)))


def _mostly_ordered(usable: NDArray[np.bool_]) -> bool:
    """At least :data:`MIN_USABLE_SHARE` usable and no run of bad stamps longer than
    :data:`MAX_BAD_RUN_SHARE` of the log: the bad ones are isolated."""
    n = usable.size
    if int(usable.sum()) < max(2.0, MIN_USABLE_SHARE * n):
        return False
    longest = max((end - start for start, end in _runs(~usable)), default=0)
    return longest <= max(2.0, MAX_BAD_RUN_SHARE * n)


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """The runs of consecutive True in ``mask`` as (first index, one past the last)."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _squeezed_run(
    stamps: NDArray[np.float64], anchors: NDArray[np.bool_], bad: NDArray[np.bool_],
    period: float,
) -> tuple[int, int] | None:
    """The first run of at least :data:`MIN_SQUEEZED_RUN` ``bad`` records, stamped at a
    scanner's intervals among themselves (within :data:`STEP_BAND` of ``period``, but one),
    whose anchored neighbours leave them less than half a period each, as (first record,
    records); None if there is none. A clock set back (by a time server, a reboot) stamps a
    stretch of the log before the records that precede it: placed between its neighbours, a
    minute of scans would pass in a fraction of a second, and the odometry's motion model
    with it. Its own intervals still measure time (:func:`record_order_steps`). A few bad
    stamps side by side (one early, the next repeated) are no such stretch."""
    idx = np.flatnonzero(anchors)
    for start, end in _runs(bad):
        p = int(np.searchsorted(idx, start))
        if end - start < MIN_SQUEEZED_RUN or p == 0 or p >= idx.size:
            continue  # a few records, or at an end (extrapolated by the period)
        with np.errstate(invalid="ignore"):
            steps = np.diff(stamps[start:end])
            off = ~((steps >= period / STEP_BAND) & (steps <= period * STEP_BAND))
        # the set back itself may lie inside: the longest increasing stamps can take the
        # stretch after it and leave the end of the one before
        regular = np.count_nonzero(off) <= 1
        room = stamps[idx[p]] - stamps[idx[p - 1]]
        if regular and room < 0.5 * period * (idx[p] - idx[p - 1]):
            return start, end - start
    return None


def _plausible(period: float) -> bool:
    return bool(np.isfinite(period)) and PLAUSIBLE_PERIOD_S[0] <= period <= PLAUSIBLE_PERIOD_S[1]


def _interpolate(
    stamps: NDArray[np.float64], anchors: NDArray[np.bool_], bad: NDArray[np.bool_], period: float
) -> NDArray[np.float64]:
    """``stamps`` with the ``bad`` records placed by index between their anchored neighbours
    (extrapolated by ``period`` before the first and after the last anchor)."""
    out = stamps.copy()
    idx = np.flatnonzero(anchors)
    where = np.flatnonzero(bad)
    inside = (where > idx[0]) & (where < idx[-1])
    out[where[inside]] = np.interp(where[inside], idx, stamps[idx])
    before, after = where[where < idx[0]], where[where > idx[-1]]
    out[before] = stamps[idx[0]] - period * (idx[0] - before)
    out[after] = stamps[idx[-1]] + period * (after - idx[-1])
    return out


def _why_unusable(stamps: NDArray[np.float64], usable: int) -> str:
    n = stamps.size
    finite = stamps[np.isfinite(stamps)]
    if finite.size == 0:
        return "no finite stamp"
    distinct = np.unique(finite).size
    if distinct == 1:
        return f"all {n} stamps are {finite[0]:g}"
    if distinct < 0.5 * n:
        return f"quantised: {distinct} distinct stamps for {n} records"
    steps = np.diff(finite)
    if np.count_nonzero(steps < 0) > 0.9 * steps.size:
        return "stamps decrease" + (" and are negative" if (finite < 0).any() else "")
    return f"only {usable} of {n} stamps are in time order (jumping or concatenated)"


def _record_order_period(
    stamps: NDArray[np.float64], anchors: NDArray[np.bool_], declared: float | None
) -> tuple[float, str]:
    """The period for record order and where it comes from: the declared one; else the median
    step between consecutive stamps, when most steps are not zero (it survives a log counting
    down or concatenated); else the span of the ordered stamps over their records (a quantised
    log: its steps are mostly zero, and the quantum between the others)."""
    if declared is not None and _plausible(declared):
        return declared, "period declared by the log"
    finite = stamps[np.isfinite(stamps)]
    steps = np.abs(np.diff(finite))
    moving = steps[steps > 0]
    if moving.size >= 0.5 * steps.size and moving.size:
        median = float(np.median(moving))
        # jumping stamps have steps of the order of the whole span, not of span / records
        regular = median <= 3.0 * float(np.ptp(finite)) / max(finite.size - 1, 1)
        if regular and _plausible(median):
            return median, "median step between stamps"
    idx = np.flatnonzero(anchors)
    if idx.size >= 2 and idx[-1] - idx[0] >= 0.5 * stamps.size:
        span = float(stamps[idx[-1]] - stamps[idx[0]]) / float(idx[-1] - idx[0])
        if _plausible(span):
            return span, "mean period of the ordered stamps"
    return DEFAULT_PERIOD_S, "no usable period in the log, assumed"


def plan_stamps(
    stamps: ArrayLike, declared_period_s: float | None = None, window: float = 2.0
) -> TimePlan:
    """Decide the stamp of every scan record of a log from all its raw ``stamps`` (file order).

    ``declared_period_s`` is the scan period the log states (e.g. a ROS ``scan_time``, a known
    sensor rate), used for record order; ``window`` the seconds a record may be out of order
    and still be put back in order by the reader.
    """
    raw = np.asarray(stamps, dtype=np.float64)
    n = raw.size
    if n == 0:
        return TimePlan(raw, LOG_STAMPS, 0, float("nan"))
    anchors = longest_increasing(raw)
    period = _anchor_period(raw, np.flatnonzero(anchors))
    anchors = _drop_stray_ends(raw, anchors, period, window)
    usable = anchors | _tolerated(raw, anchors, window, period)
    ordered = _mostly_ordered(usable)
    good = n == 1 or (ordered and _plausible(period))
    squeezed = None
    if good and n > 1:
        bad = ~usable
        if not bad.any():
            return TimePlan(raw, LOG_STAMPS, 0, period)
        squeezed = _squeezed_run(raw, anchors, bad, period)
        if squeezed is None:
            reason = _repair_reason(raw, bad)
            return TimePlan(_interpolate(raw, anchors, bad, period), LOG_STAMPS,
                            int(bad.sum()), period, reason)
    if n == 1:
        if np.isfinite(raw[0]):
            return TimePlan(raw, LOG_STAMPS, 0, float("nan"))
        return TimePlan(np.zeros(1), RECORD_ORDER, 1, DEFAULT_PERIOD_S, "no finite stamp")
    if squeezed is not None:
        start, count = squeezed
        why = (f"{count} records from scan record {start + 1} overlap in time with the ones "
               f"around them (a clock set back), which leave no room for them")
    elif ordered:
        why = f"median interval {period:.3g} s is not a scanner's (a unit mix-up?)"
    else:
        why = _why_unusable(raw, int(usable.sum()))
    rec_period, origin = _record_order_period(raw, anchors, declared_period_s)
    finite = raw[np.isfinite(raw)]
    t0 = float(finite[0]) if finite.size and finite[0] >= 0 and _plausible(period) else 0.0
    steps, kept = record_order_steps(raw, rec_period)
    planned = t0 + np.concatenate(([0.0], np.cumsum(steps)))
    if kept:
        origin += f"; the log's own intervals kept where they fit ({kept} of {n - 1})"
    return TimePlan(planned, RECORD_ORDER, n, rec_period, f"{why}; {origin}")


def record_order_steps(raw: NDArray[np.float64], period: float) -> tuple[NDArray[np.float64], int]:
    """The intervals between consecutive records in record order, and how many are the log's.

    Stamps that count down, or restart once (a log concatenated with itself), still measure
    the time between most records: the steps of the commoner sign are kept where they lie
    within :data:`STEP_BAND` of the period, the others (the restart, a jump, a zero step)
    become the period. When fewer than half fit (quantised or jumping stamps) all steps are
    the period.
    """
    steps = np.diff(raw)
    uniform = np.full(steps.size, period)
    moving = steps[np.isfinite(steps) & (steps != 0)]
    if moving.size == 0:
        return uniform, 0
    sign = 1.0 if np.count_nonzero(moving > 0) >= np.count_nonzero(moving < 0) else -1.0
    with np.errstate(invalid="ignore"):
        size = sign * steps
        fits = np.isfinite(size) & (size >= period / STEP_BAND) & (size <= period * STEP_BAND)
    if np.count_nonzero(fits) < 0.5 * steps.size:
        return uniform, 0
    return np.where(fits, size, period), int(np.count_nonzero(fits))


def _repair_reason(raw: NDArray[np.float64], bad: NDArray[np.bool_]) -> str:
    parts = []
    nonfinite = int(np.count_nonzero(bad & ~np.isfinite(raw)))
    if nonfinite:
        parts.append(f"{nonfinite} non-finite")
    other = int(bad.sum()) - nonfinite
    if other:
        parts.append(f"{other} out of order or repeated")
    first = int(np.flatnonzero(bad)[0])
    return ", ".join(parts) + f"; first at scan record {first + 1}"
