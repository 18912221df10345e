"""A closure check's search for a rival outside its window, with and without the check's own
search reused, paired on the same inputs in the same run.

Where the map's prediction may be farther off than a check's window, the verification seeks a
rival outside it by a branch-and-bound search of a wider window around the same prediction
(:func:`bioslam.closure.outside_rival`), handed the check's own search of its window
(:meth:`bioslam.matching.branch_and_bound.WideBasinMatcher.search`'s ``known``). This runs the
full system on each log and searches each of those wider windows twice, with the check's
search and without it, in alternating order, and asserts that both give the same best and rival.
Printed per log: the searches, the nodes bounded, the median, 90th percentile and largest time
of one search, their sum, and the median of the paired ratios (reused / whole).

Usage: ``python benchmarks/bench_outside_rival.py [--log PATH ...]`` (default: intel and
freiburg-079 from ``../shared/data``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bioslam import closure
from bioslam.config import SLAMConfig
from bioslam.io.logs import open_log
from bioslam.pipeline import warm_up
from bioslam.slam import BioSLAM

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DEFAULT_LOGS = (DATA / "intel-corrected.log.gz", DATA / "freiburg-079-corrected.log.gz")


def paired_searches(log: Path) -> np.ndarray:
    """Rows of (ms whole, ms reused, nodes whole, nodes reused, slide) for each wider search
    of a run of the full system on ``log``."""
    rows: list[tuple[float, float, int, int, bool]] = []
    search = closure._wide_search

    def both(matcher, query, centre, window, config, slide=None, known=None):
        if known is None:
            return search(matcher, query, centre, window, config, slide)
        timed = {}
        for reuse in (False, True) if len(rows) % 2 else (True, False):
            started = time.perf_counter()
            found = search(matcher, query, centre, window, config, slide, known if reuse else None)
            timed[reuse] = (1e3 * (time.perf_counter() - started), found)
        whole, reused = timed[False][1], timed[True][1]
        assert np.array_equal(whole.pose, reused.pose), "the best differs"
        assert (whole.rival_pose is None) == (reused.rival_pose is None), "the rival differs"
        if whole.rival_pose is not None:
            assert np.array_equal(whole.rival_pose, reused.rival_pose), "the rival differs"
        rows.append((timed[False][0], timed[True][0], whole.match.nodes, reused.match.nodes,
                     slide is not None))  # fmt: skip
        return reused

    closure._wide_search = both
    try:
        slam = BioSLAM(SLAMConfig())
        for scan in open_log(log):
            slam.process(scan)
    finally:
        closure._wide_search = search
    return np.array(rows, dtype=np.float64).reshape(-1, 5)


def report(name: str, rows: np.ndarray) -> str:
    if not len(rows):
        return f"{name}: no search outside a check's window"
    whole, reused = rows[:, 0], rows[:, 1]

    def times(ms: np.ndarray) -> str:
        return (f"{np.median(ms):.2f} / {np.percentile(ms, 90):.2f} / {ms.max():.2f} ms, "
                f"sum {ms.sum():.0f} ms")  # fmt: skip

    slid = rows[:, 4] > 0
    return (
        f"{name}: {len(rows)} searches outside a check's window; nodes {int(rows[:, 2].sum())} "
        f"-> {int(rows[:, 3].sum())} ({int(slid.sum())} across a slide: "
        f"{int(rows[slid, 2].sum())} -> {int(rows[slid, 3].sum())})\n"
        f"  median / 90th percentile / largest, whole: {times(whole)}\n"
        f"  the check's search reused:                 {times(reused)}\n"
        f"  median of the paired ratios {np.median(reused / whole):.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--log", action="append", type=Path, help="a log (repeatable)")
    args = parser.parse_args()
    logs = args.log or [p for p in DEFAULT_LOGS if p.exists()]
    if not logs:
        raise SystemExit(f"no log given and none found in {DATA}")
    print(f"warm-up: {warm_up(SLAMConfig()):.1f} s")
    for log in logs:
        print(report(log.name, paired_searches(log)))


if __name__ == "__main__":
    main()
