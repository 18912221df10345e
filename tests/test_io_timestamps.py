"""A log's stamps checked as a whole: isolated bad stamps repaired, unusable ones replaced by
record order, clean logs untouched (unit cases, then the shared logs with each defect)."""

from __future__ import annotations

import functools
import gzip

import numpy as np
import pytest
from _io_data import shared_log

from bioslam.io.defects import (
    BREEZYSLAM_DEFECTS,
    CARMEN_DEFECTS,
    breezyslam_with_defect,
    carmen_with_defect,
)
from bioslam.io.logs import open_log
from bioslam.io.timestamps import (
    DEFAULT_PERIOD_S,
    LOG_STAMPS,
    RECORD_ORDER,
    longest_increasing,
    plan_stamps,
)

RNG = np.random.default_rng(7)
# 10 Hz with jitter, starting at an epoch-like time: the stamps of a healthy log
CLEAN = 1.2e9 + np.cumsum(0.1 + 0.01 * RNG.random(300))


def test_clean_stamps_are_kept_bit_for_bit():
    plan = plan_stamps(CLEAN)
    assert plan.source == LOG_STAMPS and plan.repaired == 0 and plan.describe() == LOG_STAMPS
    assert plan.stamps.tobytes() == CLEAN.tobytes()
    assert plan.period_s == pytest.approx(0.105, abs=0.002)


def test_slightly_late_records_keep_their_stamps_for_the_reorder():
    stamps = CLEAN.copy()
    stamps[[50, 51]] = stamps[[51, 50]]  # two records swapped: 0.1 s out of order
    stamps[120] -= 0.8  # stored late by a second logger process
    plan = plan_stamps(stamps, window=2.0)
    assert plan.repaired == 0 and plan.stamps.tobytes() == stamps.tobytes()


def test_records_stamped_early_keep_their_place_in_the_file():
    """Without a reorder window (the readers' default) the same records are stamp errors:
    each is placed between its neighbours in the file, and every other stamp is kept."""
    stamps = CLEAN.copy()
    stamps[[50, 51]] = stamps[[51, 50]]
    stamps[120] -= 0.8
    plan = plan_stamps(stamps, window=0.0)
    assert plan.source == LOG_STAMPS and plan.repaired == 2
    assert np.all(np.diff(plan.stamps) > 0)
    kept = plan.stamps == stamps
    assert np.count_nonzero(~kept) == 2 and not kept[120]


def test_a_clock_set_back_keeps_the_logs_own_intervals():
    """A clock set back 2 s after 300 records of a 10 Hz log: the next 20 records are stamped
    before the ones around them, which leave them 0.1 s. Placed between those, they would
    pass in 5 ms each; in record order with the log's own intervals (the one back replaced by
    the period) every record is 0.1 s after the one before."""
    stamps = np.concatenate([np.arange(300) * 0.1, 28.0 + np.arange(300) * 0.1])
    plan = plan_stamps(stamps, window=0.0)
    assert plan.source == RECORD_ORDER
    assert "20 records from scan record" in plan.reason and "clock set back" in plan.reason
    np.testing.assert_allclose(plan.stamps, np.arange(600) * 0.1, atol=1e-9)


@pytest.mark.parametrize("index", [0, 1, 150, 298, 299])
@pytest.mark.parametrize("bad", [np.nan, np.inf, 0.0, -5.0, 3600.0, 1e12])
def test_an_isolated_bad_stamp_is_interpolated_and_nothing_else_changes(index, bad):
    stamps = CLEAN.copy()
    stamps[index] = bad if bad in (0.0, -5.0) or not np.isfinite(bad) else stamps[index] + bad
    plan = plan_stamps(stamps)
    assert plan.source == LOG_STAMPS and plan.repaired == 1
    others = np.arange(stamps.size) != index
    assert plan.stamps[others].tobytes() == CLEAN[others].tobytes()
    assert np.all(np.diff(plan.stamps) > 0)
    # between its neighbours (or one median period beyond the last one)
    assert plan.stamps[index] == pytest.approx(CLEAN[index], abs=0.12)
    assert f"scan record {index + 1}" in plan.reason


def test_scattered_repeats_and_nans_are_repaired_one_by_one():
    stamps = CLEAN.copy()
    stamps[10::25] = stamps[9::25][: stamps[10::25].size]  # every 25th repeats its predecessor
    stamps[17::40] = np.nan
    plan = plan_stamps(stamps)
    bad = int(np.count_nonzero(stamps[1:] == stamps[:-1]) + np.isnan(stamps).sum())
    assert plan.source == LOG_STAMPS and plan.repaired == bad
    assert np.all(np.diff(plan.stamps) > 0)
    np.testing.assert_allclose(plan.stamps, CLEAN, atol=0.11)


def _quantised(t):
    return np.array([float(f"{v:.9g}") for v in t])  # 1.2e9 s to 10 s: 100 scans per stamp


@pytest.mark.parametrize(
    ("name", "change", "reason"),
    [
        ("all zero", lambda t: np.zeros_like(t), "all 300 stamps are 0"),
        ("constant", lambda t: np.full_like(t, 1.5e9), "all 300 stamps"),
        ("nine digits", _quantised, "quantised"),
        ("decreasing", lambda t: t[::-1].copy(), "stamps decrease"),
        ("negative", lambda t: -t, "stamps decrease and are negative"),
        ("concatenated", lambda t: np.concatenate([t[:150], t[:150]]), "in time order"),
        ("jumping", lambda t: RNG.permutation(t), "in time order"),
        ("µs read as s", lambda t: t * 1e-6, "not a scanner's"),
        ("all NaN", lambda t: np.full_like(t, np.nan), "no finite stamp"),
    ],
)
def test_unusable_stamps_give_record_order(name, change, reason):
    plan = plan_stamps(change(CLEAN.copy()))
    assert plan.source == RECORD_ORDER, name
    assert reason in plan.reason, plan.reason
    assert plan.repaired == CLEAN.size
    steps = np.diff(plan.stamps)
    assert np.all(steps > 0)
    if "own intervals" in plan.reason:  # counting down or restarting: the log's steps kept
        own = np.abs(np.diff(change(CLEAN.copy())))
        fits = own < 20 * plan.period_s
        np.testing.assert_allclose(steps[fits], own[fits], atol=1e-5)
        np.testing.assert_allclose(steps[~fits], plan.period_s, atol=1e-5)
        assert name in ("decreasing", "negative", "concatenated")
    else:
        np.testing.assert_allclose(steps, plan.period_s, atol=1e-5)
    assert plan.describe().startswith(f"record order at {1 / plan.period_s:.4g} Hz")


def test_record_order_uses_the_declared_period_first():
    plan = plan_stamps(np.zeros(50), declared_period_s=0.025)
    assert plan.period_s == 0.025 and "declared" in plan.reason
    assert plan_stamps(np.zeros(50)).period_s == DEFAULT_PERIOD_S
    # an implausible declared period is not used
    assert plan_stamps(np.zeros(50), declared_period_s=1e-9).period_s == DEFAULT_PERIOD_S


def test_record_order_rate_comes_from_the_stamps_when_not_declared():
    # counting down or concatenated: the step between stamps is still the scan period
    assert plan_stamps(CLEAN[::-1].copy()).period_s == pytest.approx(0.105, abs=0.002)
    # quantised to 10 s: most steps are zero, the span over the records gives the period
    quantised = np.floor(np.arange(3000) * 0.05 / 10.0) * 10.0
    assert plan_stamps(quantised).period_s == pytest.approx(0.05, rel=0.01)


def test_longest_increasing_leaves_out_the_spike():
    t = np.array([1.0, 2.0, 10.0, 3.0, 4.0, np.nan, 5.0])
    np.testing.assert_array_equal(longest_increasing(t), [1, 1, 0, 1, 1, 0, 1])
    assert not longest_increasing(np.array([np.nan])).any()


# -- the shared logs --------------------------------------------------------------------------

def _carmen_laser_stamps(lines):
    return [float(line.split()[-3]) for line in lines if line.startswith("FLASER ")]


def _carmen_laser_x(lines):
    return [float(f[2 + int(f[1])]) for f in (line.split() for line in lines) if f[0] == "FLASER"]


@pytest.mark.parametrize(
    ("name", "early"), [("intel-corrected.log.gz", 4), ("freiburg-079-corrected.log.gz", 0)]
)
def test_clean_carmen_logs_keep_their_stamps_and_their_order(name, early):
    """Every scan in file order with its own stamp, but those stamped before the scan
    written ahead of them (intel: four, 0.1-0.86 s early, whose corrected poses follow the
    file's order, not the stamps'), which are repaired between their neighbours."""
    path = shared_log(name)
    with gzip.open(path, "rt", encoding="latin-1") as fh:
        lines = fh.readlines()
    raw, x = np.array(_carmen_laser_stamps(lines)), np.array(_carmen_laser_x(lines))
    source = open_log(path)
    stamps = np.array([s.stamp for s in source])
    assert stamps.size == raw.size and np.all(np.diff(stamps) > 0)
    assert np.count_nonzero(stamps != raw) == early
    assert source.time_source.startswith(LOG_STAMPS)
    assert (f"{early} repaired" in source.time_source) == (early > 0)
    np.testing.assert_array_equal(source.reference.poses[:, 0], x)  # the file's order


def test_clean_exp1_and_bag_keep_their_stamps():
    path = shared_log("exp1.dat")
    raw = [float(line.split()[0]) * 1e-6 for line in path.open() if line.strip()]
    source = open_log(path)
    assert [s.stamp for s in source] == raw and source.time_source == LOG_STAMPS
    bag = open_log(shared_log("laser_scan_matcher_demo.bag"))
    assert sum(1 for _ in bag) == 360 and bag.time_source == LOG_STAMPS


def _defect_cases():
    for defect in CARMEN_DEFECTS:
        yield "intel-corrected.log.gz", defect
    for defect in BREEZYSLAM_DEFECTS:
        yield "exp1.dat", defect


@functools.cache
def _clean(name):
    """Lines, scan count and duration of a clean shared log (read once per session)."""
    path = shared_log(name)
    opener = gzip.open if name.endswith(".gz") else open
    with opener(path, "rt", encoding="latin-1") as fh:
        lines = fh.readlines()
    stamps = [s.stamp for s in open_log(path)]
    return lines, len(stamps), stamps[-1] - stamps[0]


@pytest.mark.parametrize(("name", "defect"), list(_defect_cases()))
def test_shared_logs_with_a_stamp_defect_are_read_whole(tmp_path, name, defect):
    lines, count, clean_duration = _clean(name)
    mutate = carmen_with_defect if name.endswith(".log.gz") else breezyslam_with_defect
    mutated = tmp_path / name.replace(".gz", "")
    mutated.write_text("".join(mutate(lines, defect)), encoding="latin-1")
    expected = count * (2 if defect == "concatenated" else 1)
    source = open_log(mutated)
    scans = list(source)
    assert len(scans) >= 0.99 * expected, source.time_source
    assert source.records_seen == expected
    stamps = np.array([s.stamp for s in scans])
    assert np.all(np.diff(stamps) > 0)
    assert any("time stamps:" in note for note in source.notes())
    if defect == "one-hour-late":  # only the bad one changes (and intel's four early ones)
        early = 4 if name.startswith("intel") else 0
        assert source.time_plan.repaired == 1 + early
        assert source.time_source.startswith(f"log stamps ({1 + early} repaired")
    else:
        assert source.time_source.startswith("record order"), source.time_source
        # the rate comes from the sensor (exp1: URG-04LX 10 Hz) or the stamps themselves
        duration = stamps[-1] - stamps[0]
        # a clock set back loses no time: the log's own intervals still measure it
        if name == "exp1.dat" or defect in ("decreasing", "negative", "concatenated", "set-back"):
            factor = 2 if defect == "concatenated" else 1
            assert duration == pytest.approx(factor * clean_duration, rel=0.15)
    if source.odometry is not None:
        assert len(source.odometry) > 0 and np.all(np.diff(source.odometry.stamps) > 0)


def test_carmen_falls_back_to_the_logger_stamps_when_the_ipc_ones_are_unusable(tmp_path):
    from _log_fixtures import PERIOD_S, SCANS, carmen_text

    lines = []
    for line in carmen_text().splitlines(keepends=True):
        fields = line.split()
        if fields and fields[0] in ("FLASER", "ODOM"):
            fields[-3] = "0"  # the ipc_timestamp, as in logs whose IPC clock was never set
            line = " ".join(fields) + "\n"
        lines.append(line)
    path = tmp_path / "ipc-zero.log"
    path.write_text("".join(lines))
    source = open_log(path)
    stamps = np.array([s.stamp for s in source])
    assert source.time_source.startswith("log stamps: logger_timestamp (the main stamps are "
                                         "unusable: all 30 stamps are 0")
    np.testing.assert_allclose(np.diff(stamps), PERIOD_S, atol=1e-6)  # the real 10 Hz
    assert len(stamps) == SCANS and stamps[0] == pytest.approx(1_600_000_000.0)
    # the odometry is placed between the scans around it, in record order
    odo = source.odometry.stamps
    assert len(odo) == 2 * SCANS and np.all(np.diff(odo) > 0)
    assert odo[2] < stamps[1] < odo[4]


def test_bag_falls_back_to_the_record_times_when_header_stamps_are_unusable(tmp_path):
    from _log_fixtures import PERIOD_S, laser_scans, write_ros1_bag

    scans = laser_scans()
    path = tmp_path / "decreasing-headers.bag"
    # header stamps count down; the record times (when the recorder got them) are right
    write_ros1_bag(path, scans, stamps=[2e9 - s.stamp for s in scans])
    source = open_log(path)
    stamps = np.array([s.stamp for s in source])
    assert source.time_source.startswith("log stamps: bag record time")
    np.testing.assert_allclose(stamps, [s.stamp for s in scans], atol=1e-6)
    assert np.diff(stamps) == pytest.approx(PERIOD_S, abs=1e-6)
