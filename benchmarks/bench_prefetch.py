"""Loop-closure checks with the submap fused on a scan ahead of the check
(``loop_closure.prefetch_submaps``, :meth:`bioslam.slam.BioSLAM._prefetch_submap`) and without,
paired scan by scan in the same run.

Two full systems, one with the setting and one without, take every scan in turn, which goes
first alternating from scan to scan (as ``bench_loops.py`` pairs the full system with its
odometry), so that whatever else loads the machine weighs on both alike. Printed per case, for
each: the per-scan wall time's median, 99th percentile and mean, and on the scans that ran a
check's registration its median and 90th percentile; the submaps built ahead and those a check
used. The script asserts that both end with the same checks, closures and trajectory.

Usage: ``python benchmarks/bench_prefetch.py [--cases world-lidar-route,...] [--log PATH ...]
[--duration S] [--seed N]`` (default: three of ``bench_loops.py``'s cases, intel and
freiburg-079 from ``../shared/data``).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from bench_loops import sim_cases, simulate, wall_ms
from cases import DATA_DIR

from bioslam.config import SLAMConfig
from bioslam.io.logs import open_log
from bioslam.pipeline import warm_up
from bioslam.slam import BioSLAM

DEFAULT_CASES = "warehouse-sick-tour,maze-rplidar-adversarial,maze-utm30lx-adversarial"
DEFAULT_LOGS = (DATA_DIR / "intel-corrected.log.gz", DATA_DIR / "freiburg-079-corrected.log.gz")


def paired_run(scans: list) -> tuple[dict[bool, BioSLAM], dict[bool, np.ndarray], np.ndarray]:
    """Both systems on ``scans``, scan by scan: each one's per-scan wall ms, and which scans
    ran a check's registration (the same scans for both, asserted at the end)."""
    config = SLAMConfig()
    systems = {
        ahead: BioSLAM(dataclasses.replace(config, loop_closure=dataclasses.replace(
            config.loop_closure, prefetch_submaps=ahead)))
        for ahead in (False, True)
    }  # fmt: skip
    ms = {ahead: np.empty(len(scans)) for ahead in systems}
    checked = np.zeros(len(scans), dtype=bool)
    for k, scan in enumerate(scans):
        asked = systems[False].submaps.requests
        for ahead in (False, True) if k % 2 else (True, False):
            ms[ahead][k] = wall_ms(systems[ahead].process, scan)
        checked[k] = systems[False].submaps.requests > asked
    for slam in systems.values():
        slam.finish()
    plain, fetched = systems[False], systems[True]
    assert _outcomes(plain) == _outcomes(fetched), "the checks differ"
    assert np.array_equal(plain.trajectory().poses, fetched.trajectory().poses), "trajectory"
    return systems, ms, checked


def _outcomes(slam: BioSLAM) -> list[tuple]:
    return [(c.stamp, c.verdict.reason, c.verdict.score, *c.verdict.pose) for c in slam.checks]


def report(name: str, scans: list) -> str:
    systems, ms, checked = paired_run(scans)
    closures = systems[True].summary()["loop_closures"]
    lines = [f"{name} ({len(scans)} scans, {int(checked.sum())} with a check's registration, "
             f"{closures} closures, the same either way)"]  # fmt: skip
    for ahead in (False, True):
        t, submaps = ms[ahead], systems[ahead].submaps
        built = f"; submaps built ahead {submaps.prefetched}, used {submaps.prefetch_used}"
        lines.append(
            f"  {'built ahead' if ahead else 'at the check'}: per-scan ms median "
            f"{np.median(t):.2f} p99 {np.percentile(t, 99):.2f} mean {t.mean():.2f}; scans with "
            f"a check median {np.median(t[checked]):.2f} p90 {np.percentile(t[checked], 90):.2f}"
            + (built if ahead else "")
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=DEFAULT_CASES, help="world-lidar-route names ('' none)")
    ap.add_argument("--log", action="append", type=Path, help="a log to run (repeatable)")
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    try:
        cases = sim_cases(args.cases)
    except ValueError as error:
        ap.error(f"--cases: {error}")
    warm_up(SLAMConfig())
    for case in cases:
        print(report(case.name, simulate(case, args.duration, args.seed)[0]), flush=True)
    for log in args.log or [p for p in DEFAULT_LOGS if p.exists()]:
        print(report(log.name, list(open_log(log))), flush=True)


if __name__ == "__main__":
    main()
