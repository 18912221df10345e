"""What keeps a run's memory small: the modules it imports, the log it keeps, the figure's
working copies. (How much memory a run takes is measured by benchmarks/bench_memory.py.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

import bioslam.io.logs as logs
from bioslam.matching.correlative import neighbourhood_max

SRC = Path(__file__).resolve().parents[1] / "src"


@pytest.mark.parametrize("shape", [(7,), (1, 5), (4, 1), (3, 4, 5), (1, 1, 1), (2, 9, 6)])
def test_neighbourhood_max_is_scipys_maximum_filter(shape):
    rng = np.random.default_rng(len(shape) * 10 + shape[-1])
    # few distinct values: ties everywhere, the case where a local maximum is ambiguous
    values = rng.integers(0, 4, size=shape).astype(np.float64)
    expected = ndimage.maximum_filter(values, size=3, mode="nearest")
    np.testing.assert_array_equal(neighbourhood_max(values), expected)
    smooth = rng.normal(size=shape)
    np.testing.assert_array_equal(
        neighbourhood_max(smooth), ndimage.maximum_filter(smooth, size=3, mode="nearest")
    )


def test_neighbourhood_max_of_booleans_is_a_binary_dilation():
    rng = np.random.default_rng(3)
    for shape in [(1, 1), (5, 1), (12, 17)]:
        mask = rng.random(shape) < 0.1
        expected = ndimage.binary_dilation(mask, np.ones((3, 3), dtype=bool))
        got = neighbourhood_max(mask)
        assert got.dtype == bool
        np.testing.assert_array_equal(got, expected)


def test_a_run_without_loop_closures_imports_neither_scipy_nor_matplotlib():
    """The odometry's warm-up and scan loop, then what a loop closure adds: SciPy arrives
    only with the map's first solve (20-25 MB that a run never closing a loop does not pay)."""
    script = """
import json, sys
from bioslam.config import SLAMConfig
from bioslam.pipeline import RunOptions, run_slam, warm_up
from bioslam.sim import LIDAR_PRESETS, maze_world, simulate_scans
from bioslam.pipeline import _drive
warm_up(SLAMConfig(), odometry_only=True)
world = maze_world()
scans = [s for s, _ in simulate_scans(world, LIDAR_PRESETS["sick"], _drive(world, 2.0))]
result = run_slam(scans, SLAMConfig(), RunOptions(odometry_only=True, progress=False,
                                                  warm_up=False))
HEAVY = ("scipy.sparse", "scipy.ndimage", "matplotlib")  # Numba loads scipy.linalg's BLAS
def heavy():
    return sorted({m.split(".")[0] for m in sys.modules if m.startswith(HEAVY)})
before = heavy()
warm_up(SLAMConfig())
after = heavy()
print(json.dumps([result.system.num_scans, before, after]))
"""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         env=env, check=True)  # fmt: skip
    scans, before, after = json.loads(out.stdout.strip().splitlines()[-1])
    assert scans > 10
    assert before == []
    assert after == ["scipy"]  # the full warm-up closes a loop


def _carmen_log(path: Path) -> Path:
    """Scans with odometry between them, one late stamp (repaired) and a malformed record."""
    lines = []
    for k in range(30):
        stamp = 100.0 + 0.1 * k + (5.0 if k == 12 else 0.0)
        ranges = " ".join(f"{2.0 + 0.01 * ((k + b) % 7):.3f}" for b in range(9))
        lines.append(f"FLASER 9 {ranges} 0 0 0 0 0 0 {stamp:.3f} host {stamp:.3f}\n")
        lines.append(f"ODOM {0.05 * k:.3f} 0 0 0 0 0 {stamp + 0.05:.3f} host {stamp + 0.05:.3f}\n")
        if k == 20:
            lines.append("FLASER 9 1 2 3\n")
    path.write_text("".join(lines))
    return path


def _read(path: Path) -> tuple:
    source = logs.open_log(path)
    scans = [(scan.stamp, scan.ranges.tobytes()) for scan in source]
    return scans, source.skipped, source.odometry, source.time_source


@pytest.mark.parametrize("budget", [0, 2000])
def test_a_log_longer_than_the_replay_budget_reads_the_same(tmp_path, monkeypatch, budget):
    """A log whose planning pass is not kept (all of it, or past the first records) is parsed
    again: the scans, stamps, repairs, skips and odometry are those of the replayed read."""
    path = _carmen_log(tmp_path / "a.log")
    scans, skipped, odometry, source = _read(path)
    assert len(scans) == 30 and skipped and "repaired" in source
    monkeypatch.setattr(logs, "REPLAY_BUDGET_BYTES", budget)
    again, skipped_again, odometry_again, source_again = _read(path)
    assert again == scans
    assert skipped_again == skipped and source_again == source
    np.testing.assert_array_equal(odometry_again.stamps, odometry.stamps)
    np.testing.assert_array_equal(odometry_again.poses, odometry.poses)


def test_the_replayed_planning_pass_is_freed_as_the_run_reads_it(tmp_path):
    """A log kept from its planning pass is not held until the last scan: a record the run
    has read is dropped (its ranges freed), while those still to come are kept."""
    import gc
    import weakref

    source = logs.open_log(_carmen_log(tmp_path / "a.log"))
    assert source.time_plan.stamps.size == 30  # planned (and kept) before the run reads it
    kept = [event[1].ranges for event in source._replay if event[0] == logs._SCAN]
    first, last = weakref.ref(kept[0]), weakref.ref(kept[-1])
    del kept
    scans = iter(source)
    for _ in range(10):
        next(scans)  # read and dropped, as the run does
    gc.collect()
    assert first() is None
    assert last() is not None
    assert len(list(scans)) == 20


TIMING = {"wall_s", "startup_s", "realtime_factor", "ms_per_scan_median", "ms_per_scan_p99"}


@pytest.mark.parametrize("odometry_only", [False, True])
def test_releasing_the_working_memory_writes_the_same_results(tmp_path, odometry_only):
    """``RunOptions.release`` drops the system's per-scan state before the map and figures:
    every output is that of a run that kept it."""
    from loop_world import ring_route, ring_world

    from bioslam.pipeline import RunOptions, run_slam, write_results
    from bioslam.sim import LIDAR_PRESETS, simulate_scans

    pairs = simulate_scans(ring_world(), LIDAR_PRESETS["urg04lx"], ring_route(laps=0.6), seed=1)
    scans = [scan for scan, _ in pairs]
    options = RunOptions(progress=False, odometry_only=odometry_only)
    result = run_slam(scans, options=options)
    kept = write_results(result, tmp_path / "kept", options=options)
    released_options = RunOptions(progress=False, odometry_only=odometry_only, release=True)
    released = write_results(result, tmp_path / "released", options=released_options)
    assert result.system.self_motion.odometry is None and len(result.keyframes) == 0
    assert len(result.system.trajectory()) == 0  # the per-scan columns went after use
    assert released["scans"] == kept["scans"] == len(scans)
    assert {k: v for k, v in released.items() if k not in TIMING} == {
        k: v for k, v in kept.items() if k not in TIMING
    }
    names = ["trajectory.tum", "odometry.tum", "map.pgm", "map.yaml"]
    names += [] if odometry_only else ["cognitive_map.json", "closures.csv"]
    for name in names:
        released_bytes = (tmp_path / "released" / name).read_bytes()
        assert released_bytes == (tmp_path / "kept" / name).read_bytes(), name
    figures = sorted(p.name for p in (tmp_path / "kept" / "figures").iterdir())
    assert figures == sorted(p.name for p in (tmp_path / "released" / "figures").iterdir())
    assert len(figures) >= (1 if odometry_only else 3)


def test_the_submap_cache_keeps_at_most_its_bytes_and_rebuilds_the_same():
    from bioslam.closure import SubmapCache
    from bioslam.config import LoopClosureConfig

    side = np.linspace(-3.0, 3.0, 120)
    room = np.concatenate([np.column_stack([side, np.full_like(side, v)]) for v in (-3, 3)]
                          + [np.column_stack([np.full_like(side, v), side]) for v in (-3, 3)])
    poses = np.array([(0.3 * k, 0.1 * k, 0.05 * k) for k in range(6)])
    rng = np.random.default_rng(4)
    payloads = [(room - p[:2] + rng.normal(0, 0.01, room.shape)).astype(np.float32)
                for p in poses]  # fmt: skip
    config = LoopClosureConfig()
    unbounded = SubmapCache(max_bytes=2**40)
    one = unbounded.get(poses, payloads, 1, range(3), config)
    size = unbounded._bytes
    assert size > 0
    cache = SubmapCache(max_bytes=int(1.5 * size))
    first = cache.get(poses, payloads, 1, range(3), config)
    cache.get(poses, payloads, 4, range(3, 6), config)  # evicts the first
    assert len(cache._items) == 1 and cache._bytes <= 1.5 * size
    again = cache.get(poses, payloads, 1, range(3), config)
    assert again is not first and cache.builds == 3 and cache.hits == 0
    np.testing.assert_array_equal(again.points, one.points)
    np.testing.assert_array_equal(again.seen.mask, one.seen.mask)


_CHURN = """
import re, sys
import numpy as np
from bioslam.memory import map_large_blocks
if sys.argv[1] == "mapped":
    assert map_large_blocks()
def rss():
    return int(re.search(r"VmRSS:\\s+(\\d+)", open("/proc/self/status").read()).group(1)) / 1024
first = np.ones(40_000)
del first  # a freed 320 kB mapping: glibc then raises its threshold above that
kept, arrays = [], []
before = rss()
for _ in range(200):  # large arrays between long-lived small ones, as a run makes them
    arrays.append(np.ones(40_000))
    kept.append(bytearray(2000))
del arrays
print(rss() - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_large_blocks_freed_between_living_ones_go_back_to_the_system():
    env = {**os.environ, "PYTHONPATH": str(SRC)}

    def resident_after_free(mode: str) -> float:
        out = subprocess.run([sys.executable, "-c", _CHURN, mode], capture_output=True,
                             text=True, env=env, check=True)  # fmt: skip
        return float(out.stdout.strip())

    assert resident_after_free("heap") > 40.0  # 64 MB made and freed, most still resident
    assert resident_after_free("mapped") < 10.0


def test_handing_free_pages_back_during_the_run_changes_nothing(monkeypatch):
    """``RunOptions.trim_every``: the allocator's free pages are handed back every so many
    scans, between scans, and the trajectory is that of a run that never does."""
    import bioslam.pipeline as pipeline
    from bioslam.pipeline import RunOptions, _drive, run_slam
    from bioslam.sim import LIDAR_PRESETS, maze_world, simulate_scans

    world = maze_world()
    scans = [s for s, _ in simulate_scans(world, LIDAR_PRESETS["sick"], _drive(world, 1.0))]
    calls = []
    monkeypatch.setattr(pipeline, "release_free_memory", lambda: calls.append(1) or True)

    def run(every: int):
        options = RunOptions(odometry_only=True, progress=False, warm_up=False, trim_every=every)
        return run_slam(scans, options=options).system.trajectory()

    plain, trimmed = run(0), run(3)
    assert calls and len(calls) == len(scans) // 3
    np.testing.assert_array_equal(trimmed.poses, plain.poses)


def test_the_command_starts_numpy_with_one_blas_thread_unless_told_otherwise():
    """``bioslam`` sizes NumPy's BLAS pool before NumPy loads (importing the command must
    not load it); a thread count the user set is kept."""
    from bioslam.cli import BLAS_THREAD_VARIABLES, single_threaded_blas

    environ = {"OMP_NUM_THREADS": "4"}
    single_threaded_blas(environ)
    assert environ["OMP_NUM_THREADS"] == "4"
    assert all(environ[name] == "1" for name in BLAS_THREAD_VARIABLES if name != "OMP_NUM_THREADS")
    if not Path("/proc/self/status").exists():
        pytest.skip("threads are counted from /proc")
    script = """
import os, re, sys
import bioslam.cli
assert "numpy" not in sys.modules, "importing the command loaded NumPy"
if sys.argv[1] == "command":
    bioslam.cli.single_threaded_blas(os.environ)
import numpy as np
a = np.random.default_rng(0).normal(size=(600, 600))
for _ in range(3):
    a = a @ a / 600.0  # large enough for OpenBLAS to use its whole pool
print(re.search(r"Threads:\\s+(\\d+)", open("/proc/self/status").read()).group(1))
"""
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    env["PYTHONPATH"] = str(SRC)

    def threads(mode: str) -> int:
        out = subprocess.run([sys.executable, "-c", script, mode], capture_output=True,
                             text=True, env=env, check=True)  # fmt: skip
        return int(out.stdout.strip().splitlines()[-1])

    assert threads("command") == 1
    if (os.cpu_count() or 1) > 1:
        assert threads("default") > 1  # what the command avoids


def test_the_command_exits_with_its_code_its_output_flushed_and_its_exit_handlers_run(tmp_path):
    """``bioslam`` skips the interpreter's teardown at exit, not what a normal exit does."""
    marker = tmp_path / "handler-ran"
    script = f"""
import atexit, sys
from bioslam.cli import exit_without_teardown
atexit.register(lambda: open({str(marker)!r}, "w").write("yes"))
sys.stdout.write("buffered, no newline")
sys.stderr.write("to stderr")
exit_without_teardown(3)
"""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert out.returncode == 3
    assert out.stdout == "buffered, no newline" and out.stderr == "to stderr"
    assert marker.read_text() == "yes"


def test_llvm_pages_dropped_after_compiling_come_back_when_compiling_again():
    """After Numba has compiled, LLVM's code pages leave the process's resident set; a later
    compilation (a kernel with a new signature) still works, faulting back what it needs,
    and a kernel compiled before still gives its result."""
    script = """
import json
import numba
from bioslam.memory import COMPILER_LIBRARIES, _file_mappings, drop_file_pages

@numba.njit(cache=False)
def total(values):
    out = 0.0
    for v in values:
        out += v * 2.0
    return out

first = total(numba.typed.List([1.0, 2.5]))
def resident():
    return sum(rss for _, _, rss, anonymous in _file_mappings(COMPILER_LIBRARIES) if not anonymous)
before = resident()
dropped = drop_file_pages(COMPILER_LIBRARIES)
after = resident()
again = total(numba.typed.List([1.0, 2.5]))
new = total(numba.typed.List([3, 4]))  # int64: compiled now, with LLVM's pages dropped
print(json.dumps([before, dropped, after, first, again, new]))
"""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         env=env, check=True)  # fmt: skip
    before, dropped, after, first, again, new = json.loads(out.stdout.strip().splitlines()[-1])
    assert before > 20 * 2**20  # compiling touched tens of MB of LLVM's code
    assert dropped >= 0.9 * before
    assert after < 0.1 * before
    assert first == again == 7.0
    assert new == 14


def test_a_mapping_with_written_pages_is_not_dropped(tmp_path):
    """A private mapping of a file whose pages were written (as a library's relocated data)
    keeps them: dropping would bring back the file's contents."""
    import mmap

    from bioslam.memory import _file_mappings, drop_file_pages

    path = tmp_path / "written-library.bin"
    path.write_bytes(b"\0" * mmap.PAGESIZE * 4)
    with open(path, "r+b") as fh:
        mapped = mmap.mmap(fh.fileno(), 0, flags=mmap.MAP_PRIVATE)
    mapped[:4] = b"kept"
    _ = mapped[mmap.PAGESIZE * 3]  # a clean page resident too
    [(_, _, rss, anonymous)] = _file_mappings(("written-library",))
    assert rss >= 2 * mmap.PAGESIZE and anonymous == mmap.PAGESIZE
    assert drop_file_pages(("written-library",)) == 0
    assert mapped[:4] == b"kept"
    mapped.close()


def test_the_log_is_read_in_a_child_forked_before_numba_is_imported(tmp_path):
    """The reader's private memory is mostly the run's pages as they were at the fork and
    rewritten since: it is forked before the settings bring in Numba and SciPy."""
    script = """
import json, sys
import bioslam.io.readahead as readahead
seen = []
original = readahead.ReadAhead.__init__
def spy(self, *args, **kwargs):
    seen.append(sorted(m for m in ("numba", "scipy", "llvmlite") if m in sys.modules))
    original(self, *args, **kwargs)
readahead.ReadAhead.__init__ = spy
readahead.can_fork = lambda: True
from bioslam.cli import main
code = main(sys.argv[1:])
print(json.dumps([code, seen]))
"""
    log = _carmen_log(tmp_path / "log.clf")
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    out = subprocess.run([sys.executable, "-c", script, "run", str(log), "--out",
                          str(tmp_path / "out"), "--no-progress", "--odometry-only"],
                         capture_output=True, text=True, env=env, check=True)  # fmt: skip
    code, seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert code == 0
    assert seen == [[]]
