"""The benchmark suite: bioslam beside the paper and a peer SLAM system, in one run.

    python benchmarks/run.py [--quick] [--repeat N] [--cases a,b] [--no-peer] [--no-install]

Writes ``benchmarks/results/<date>[-quick].md`` and ``.json`` and prints the table. Every row is a
fresh child process (``bioslam run`` or MRPT's ``icp-slam``), timed by wall clock and its own
peak RSS; accuracy is evaluated with ``bioslam.evaluation`` against the case's reference. A row
that fails is recorded with its error instead of aborting the run.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import numpy as np  # noqa: E402
from cases import (  # noqa: E402
    Case,
    PreparedCase,
    bioslam_cli,
    full_cases,
    prepare,
    quick_cases,
    read_reference,
)
from peers import mrpt_icp_slam as mrpt  # noqa: E402
from rows import (  # noqa: E402
    ROW_FULL,
    ROW_ODOM,
    ROW_PEER,
    RowRun,
    finalize_timing,
    prepare_peer,
    run_bioslam,
    run_peer,
)

from bioslam.evaluation import three_cornered_hat  # noqa: E402

# The paper's own published figures (Zhuang et al., Sec. IV). They come from the authors' data,
# not from these cases: the simulation row is their 600 s iRat maze run (RPE-vs-ground-truth
# mean 2.84 cm, max 12.7 cm), the indoor rows their real maze (RMSE of the position error).
PAPER_ROWS = [
    {"case": "paper: simulated maze (600 s)", "row": "bioslam (paper)",
     "ate_mean_m": 0.0284, "ate_max_m": 0.127},
    {"case": "paper: indoor maze", "row": "bioslam (paper)", "ate_rmse_m": 0.0223},
    {"case": "paper: indoor maze", "row": "Hector SLAM (paper)", "ate_rmse_m": 0.0259},
    {"case": "paper: indoor maze", "row": "Cartographer (paper)", "ate_rmse_m": 0.0797},
    {"case": "paper: indoor maze", "row": "RatSLAM (paper)", "ate_rmse_m": 0.2538},
]  # fmt: skip

COLUMNS = [  # (key, header, format)
    ("ate_rmse_m", "ATE RMSE m", "{:.3f}"),
    ("ate_mean_m", "ATE mean m", "{:.3f}"),
    ("ate_max_m", "ATE max m", "{:.3f}"),
    ("rpe_1m_trans_m", "RPE 1m m", "{:.3f}"),
    ("rpe_1m_rot_deg", "RPE 1m deg", "{:.2f}"),
    ("loop_gap_m", "loop gap m", "{:.3f}"),
    ("loop_gap_deg", "loop gap deg", "{:.1f}"),
    ("wall_s", "wall s", "{:.1f}"),
    ("ms_per_scan_median", "ms/scan med", "{:.2f}"),
    ("ms_per_scan_p99", "ms/scan p99", "{:.2f}"),
    ("realtime_factor", "RT factor", "{:.1f}"),
    ("peak_rss_mb", "peak RSS MB", "{:.0f}"),
    ("scans_per_s", "scans/s", "{:.0f}"),
    ("time_ratio_vs_peer", "time / peer", "{:.2f}"),
    ("views", "views", "{}"),
    ("experiences", "exps", "{}"),
    ("loop_closures", "loops", "{}"),
]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="short routes, one timed run (< 5 min)")
    p.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="timed runs per row on cases that allow it; medians are quoted",
    )
    p.add_argument("--cases", default="", help="comma-separated case names (default: all)")
    p.add_argument("--no-peer", action="store_true", help="skip MRPT icp-slam")
    p.add_argument("--no-install", action="store_true", help="never apt-get the peer")
    p.add_argument("--work", type=Path, default=HERE / ".work", help="scratch folder")
    p.add_argument("--results", type=Path, default=HERE / "results")
    return p.parse_args(argv)


def select_cases(args: argparse.Namespace) -> list[Case]:
    cases = quick_cases() if args.quick else full_cases()
    if args.cases:
        wanted = set(args.cases.split(","))
        unknown = wanted - {c.name for c in cases}
        if unknown:
            raise SystemExit(f"unknown case(s): {sorted(unknown)}")
        cases = [c for c in cases if c.name in wanted]
    return cases


def _error(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"[:300]


def bench_case(case: Case, args: argparse.Namespace, peer_ok: str) -> tuple[list[RowRun], dict]:
    """All rows of one case; timed runs interleaved so each bioslam run has a peer partner."""
    work = args.work / ("quick" if args.quick else "full")
    info: dict = {"case": case.name, "description": case.description}
    rows = {name: RowRun(name, case.name) for name in (ROW_FULL, ROW_ODOM, ROW_PEER)}
    try:
        prepared = prepare(case, work)
    except Exception as exc:  # a case that cannot be prepared is reported, not fatal
        for r in rows.values():
            r.error = f"case not prepared: {_error(exc)}"
        return list(rows.values()), info
    info.update(
        scans=len(prepared.scans),
        log_duration_s=prepared.duration_s,
        reference=bool(prepared.reference_tum),
        notes=prepared.notes,
    )
    peer_work = work / "runs" / case.name / "mrpt"
    ini = stamps = None
    if peer_ok:
        rows[ROW_PEER].error = peer_ok
    else:
        try:
            ini, stamps = prepare_peer(prepared, peer_work, mrpt.IcpSlamConfig())
        except Exception as exc:
            rows[ROW_PEER].error = _error(exc)
    repeats = max(1, min(args.repeat, case.repeats))
    for k in range(repeats):
        first = k == 0
        for name, odo in ((ROW_FULL, False), (ROW_ODOM, True)):
            if rows[name].error:
                continue
            out = work / "runs" / case.name / ("odometry" if odo else "full")
            try:
                run_bioslam(rows[name], prepared, out, odo, first)
            except Exception as exc:
                rows[name].error = _error(exc)
        if ini is not None and not rows[ROW_PEER].error:
            try:
                run_peer(rows[ROW_PEER], prepared, peer_work, ini, stamps, first)
            except Exception as exc:
                rows[ROW_PEER].error = _error(exc)
    for r in rows.values():
        finalize_timing(r, prepared.duration_s, len(prepared.scans))
    add_speed_ratios(rows)
    info.update(reference_share(prepared, rows[ROW_ODOM], rows[ROW_PEER]))
    return list(rows.values()), info


def reference_share(prepared: PreparedCase, odometry: RowRun, peer: RowRun) -> dict:
    """How much of a case's 1 m RPE is the reference's own error: a three-cornered hat of
    the reference, bioslam's odometry and the peer (independent scan matchers)."""
    ref = read_reference(prepared)
    if ref is None or odometry.trajectory is None or peer.trajectory is None:
        return {}
    hat = three_cornered_hat(ref, odometry.trajectory, peer.trajectory)
    return dict(zip(("own_rpe1m_reference_m", "own_rpe1m_odometry_m", "own_rpe1m_peer_m"),
                    hat["trans_rmse_m"], strict=True))  # fmt: skip


def add_speed_ratios(rows: dict[str, RowRun]) -> None:
    """bioslam time / peer time, pair by pair (run k of each), median over pairs."""
    peer = rows[ROW_PEER]
    for name in (ROW_FULL, ROW_ODOM):
        mine = rows[name]
        pairs = list(zip(mine.walls, peer.walls, strict=False))
        if pairs:
            ratios = [a / b for a, b in pairs]
            mine.metrics["time_ratio_vs_peer"] = float(np.median(ratios))
            mine.metrics["time_ratio_pairs"] = ratios


def _fmt(value, fmt: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    try:
        return fmt.format(value)
    except (ValueError, TypeError):
        return str(value)


def markdown_table(records: list[dict], columns: list[tuple[str, str, str]] = COLUMNS) -> str:
    head = ["case", "system", *(h for _, h, _ in columns), "error"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in records:
        cells = [r["case"], r["row"], *(_fmt(r.get(k), f) for k, _, f in columns)]
        cells.append(r.get("error", "").replace("|", "/"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def code_version() -> str:
    """The commit benchmarked, marked ``+dirty`` when the working tree has local changes."""
    import subprocess

    def git(*a: str) -> str:
        return subprocess.run(["git", *a], cwd=HERE, capture_output=True, text=True).stdout

    dirty = "+dirty" if git("status", "--porcelain", "--untracked-files=no").strip() else ""
    return git("rev-parse", "--short", "HEAD").strip() + dirty


def machine_info() -> dict:
    return {
        "code": code_version(),
        "host_cpus": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "loadavg_start": os.getloadavg(),
    }


def write_results(
    args: argparse.Namespace, records: list[dict], infos: list[dict], meta: dict
) -> Path:
    args.results.mkdir(parents=True, exist_ok=True)
    stem = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d") + ("-quick" if args.quick else "")
    save_map_pictures(records, args.results / f"{stem}-maps")
    payload = {"meta": meta, "cases": infos, "rows": records, "paper": PAPER_ROWS}
    (args.results / f"{stem}.json").write_text(json.dumps(payload, indent=1, default=float))
    md = [
        f"# bioslam benchmark {stem}",
        "",
        f"Command: `{meta['command']}` at commit {meta['code']}  ",
        f"Machine: {meta['host_cpus']} CPUs, {meta['platform']}, shared with other jobs during "
        f"the run (load average {meta['loadavg_start'][0]:.1f} at start, "
        f"{meta['loadavg_end'][0]:.1f} at end); wall {meta['total_wall_s']:.0f} s.  ",
        f"Cases completed: {len(infos)} of {meta['cases_planned']}.  ",
        f"Timed runs per row: up to {args.repeat} (medians; long simulated cases once), after "
        "an untimed 20 s demo that fills Numba's cache. `time / peer` = bioslam wall / "
        "icp-slam wall, pair by pair in the same run, median.",
        "",
        markdown_table(records),
        "",
        "## Cases",
        "",
    ]
    for info in infos:
        line = f"- **{info['case']}**: {info['description']}"
        if "scans" in info:
            line += f"; {info['scans']} scans over {info['log_duration_s']:.0f} s"
        if "own_rpe1m_reference_m" in info:
            line += (
                "; own 1 m RPE by a three-cornered hat (errors shared by two are blamed on the "
                f"third): reference {_fmt(100 * info['own_rpe1m_reference_m'], '{:.2f}')} cm, "
                f"odometry {_fmt(100 * info['own_rpe1m_odometry_m'], '{:.2f}')} cm, "
                f"icp-slam {_fmt(100 * info['own_rpe1m_peer_m'], '{:.2f}')} cm"
            )
        md.append(line)
    pictures = [
        f"- {r['case']}, {r['row']}: `{r['map_picture']}`" for r in records if "map_picture" in r
    ]
    if pictures:
        md += ["", "## Map pictures (cases without a reference)", "", *pictures]
    md += [
        "",
        "## The paper's published figures (their data, not these cases)",
        "",
        markdown_table(PAPER_ROWS, COLUMNS[:3]),
        "",
    ]
    out = args.results / f"{stem}.md"
    out.write_text("\n".join(md))
    return out


def save_map_pictures(records: list[dict], folder: Path) -> None:
    """Copy the map pictures of cases without a reference (judged by eye) as PNG into results."""
    from PIL import Image

    for rec in records:
        src = rec.get("artefacts", {}).get("map")
        if not src or "ate_rmse_m" in rec or not Path(src).exists():
            continue
        folder.mkdir(parents=True, exist_ok=True)
        slug = rec["row"].split(" (")[0].replace(" ", "-")
        dst = folder / f"{rec['case']}-{slug}.png"
        Image.open(src).convert("L").save(dst, optimize=True)
        rec["map_picture"] = str(dst.relative_to(folder.parent))


def to_record(r: RowRun) -> dict:
    rec = {"case": r.case, "row": r.row, **r.metrics, "artefacts": r.artefacts}
    if r.error:
        rec["error"] = r.error
    return rec


def warm_numba_cache(work: Path) -> None:
    """One untimed 20 s demo before the timed rows, so that Numba compiles and caches the
    kernels: in a fresh clone the first timed row otherwise pays the compilation (measured:
    freiburg's full system 42 s wall instead of 14 s, and 627 MB peak instead of ~500 MB)."""
    out = work / "warm-up"
    cmd = [*bioslam_cli(), "demo", "--duration", "20", "--out", str(out), "--no-progress",
           "--overwrite"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        print(f"[bench] warm-up failed: {proc.stderr.strip()[-400:]}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    t0 = time.perf_counter()
    meta = machine_info()
    meta["command"] = " ".join(["python benchmarks/run.py", *(argv or sys.argv[1:])])
    peer_ok = "skipped (--no-peer)" if args.no_peer else ""
    if not peer_ok:
        try:
            mrpt.ensure_installed(allow_install=not args.no_install)
        except mrpt.PeerUnavailableError as exc:
            peer_ok = _error(exc)
    records: list[dict] = []
    infos: list[dict] = []
    cases = select_cases(args)
    meta["cases_planned"] = len(cases)
    print("[bench] warm-up (Numba cache) …", file=sys.stderr, flush=True)
    warm_numba_cache(args.work)
    for case in cases:
        print(f"[bench] {case.name} …", file=sys.stderr, flush=True)
        rows, info = bench_case(case, args, peer_ok)
        records += [to_record(r) for r in rows]
        infos.append(info)
        # Written after every case, so that an interrupted full run keeps what it measured.
        meta["loadavg_end"] = os.getloadavg()
        meta["total_wall_s"] = time.perf_counter() - t0
        out = write_results(args, records, infos, meta)
    print(markdown_table(records))
    print(f"\nwritten: {out} and {out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
