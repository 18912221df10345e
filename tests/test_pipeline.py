"""The pipeline around the core: running, timing, writing results, and the `run`/`demo` CLI."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from loop_world import ring_route, ring_world

from bioslam.cli import main
from bioslam.closure import Check, Verdict
from bioslam.io.closures import read_closures, write_closures
from bioslam.io.mapfile import read_map
from bioslam.io.tum import read_tum
from bioslam.io.uncertainty import read_uncertainty
from bioslam.pipeline import RunOptions, run_slam, write_results
from bioslam.sim import LIDAR_PRESETS, simulate_scans
from bioslam.trajectory import Trajectory

RUN_KEYS = {
    "scans", "wall_s", "startup_s", "realtime_factor", "ms_per_scan_median", "ms_per_scan_p99",
    "views", "experiences", "loop_closures",
}
EVAL_KEYS = {"ate_rmse_m", "ate_mean_m", "ate_max_m", "rpe_1m_trans_m", "rpe_1m_rot_deg"}


@pytest.fixture(scope="module")
def short_drive():
    route = ring_route(laps=0.6)
    pairs = list(simulate_scans(ring_world(), LIDAR_PRESETS["urg04lx"], route, seed=1))
    scans = [s for s, _ in pairs]
    gt = Trajectory(np.array([s.stamp for s in scans]), np.array([p for _, p in pairs]))
    return scans, gt


def last_json(capsys) -> dict:
    lines = capsys.readouterr().out.strip().splitlines()
    return json.loads(lines[-1])


def test_results_are_written_and_consistent(short_drive, tmp_path):
    scans, gt = short_drive
    end = float(gt.stamps[-1] - gt.stamps[0])
    options = RunOptions(progress=False, snapshot_times=(5.0, 10.0, end + 0.5, end + 100.0))
    result = run_slam(scans, options=options)
    # The time just past the end gets the final map; one far beyond it gets nothing.
    assert [s.elapsed for s in result.snapshots] == [5.0, 10.0, end + 0.5]
    assert len(result.snapshots[-1].nodes_xy) > len(result.snapshots[0].nodes_xy)
    summary = write_results(result, tmp_path, gt, options)
    assert set(summary) >= RUN_KEYS | EVAL_KEYS
    assert summary["scans"] == len(scans)
    trajectory = read_tum(tmp_path / "trajectory.tum")
    assert len(trajectory) == len(scans) == len(read_tum(tmp_path / "odometry.tum"))
    uncertainty = read_uncertainty(tmp_path / "odometry_uncertainty.csv")
    np.testing.assert_allclose(uncertainty[:, 0], trajectory.stamps, atol=1e-6)
    assert np.all(uncertainty[1:, 8] < 0.05)  # a ring of walls pins every match down
    assert summary["ate_max_m"] < 0.1
    graph = json.loads((tmp_path / "cognitive_map.json").read_text())
    assert len(graph["nodes"]) == summary["experiences"] > 0
    assert {"from", "to", "dp", "dt", "time", "kind"} <= set(graph["links"][0])
    image = read_map(tmp_path / "map.yaml")
    occupied = np.nan_to_num(image.occupancy) > 0.65
    assert occupied.sum() > 100
    for name in ("map.png", "cognitive_map.png", "active_view.png", "error.png",
                 "views_and_error.png", "mapping_progress.png"):
        assert (tmp_path / "figures" / name).stat().st_size > 1000
    assert json.loads((tmp_path / "summary.json").read_text())["scans"] == len(scans)


def test_the_warm_up_runs_before_the_timed_scans(short_drive):
    scans, _ = short_drive
    warmed = run_slam(scans[:30], options=RunOptions(progress=False))
    cold = run_slam(scans[:30], options=RunOptions(progress=False, warm_up=False))
    assert warmed.startup_s > 0.0 and cold.startup_s == 0.0
    assert warmed.error is None
    # the same scans give the same trajectory with or without it
    np.testing.assert_allclose(
        warmed.system.trajectory().poses, cold.system.trajectory().poses, atol=1e-12
    )


# Run in a fresh interpreter: in this one, other tests have compiled kernels already.
_COMPILES_AFTER_WARM_UP = """
import importlib, pkgutil, sys
import bioslam
from bioslam.config import SLAMConfig
from bioslam.pipeline import warm_up
from bioslam.sim import LIDAR_PRESETS, make_route, maze_world, simulate_scans
from bioslam.slam import BioSLAM
names = [m.name for m in pkgutil.walk_packages(bioslam.__path__, "bioslam.")]
modules = [importlib.import_module(name) for name in names
           if not any(part in name for part in ("cli", "batch", "recording", "plots"))]
kernels = {(module.__name__, name): getattr(module, name) for module in modules
           for name in dir(module) if hasattr(getattr(module, name), "py_func")}
warm_up(SLAMConfig())
before = {key: len(kernel.signatures) for key, kernel in kernels.items()}
world = maze_world()
for lidar in ("sick361", "rplidar"):
    system = BioSLAM(SLAMConfig())
    route = make_route(world, duration=60.0, seed=1)
    for scan, _ in simulate_scans(world, LIDAR_PRESETS[lidar], route, seed=1):
        system.process(scan)
    system.finish()
print(sorted(f"{m}.{n}" for (m, n), k in kernels.items() if len(k.signatures) > before[(m, n)]))
"""


def test_after_the_warm_up_a_run_compiles_nothing():
    # A kernel first called mid-run, or called with argument types the warm-up did not use
    # (a read-only coverage array was one), is compiled there: a pause of 0.1-1 s on a
    # scan of the first run after an install.
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-c", _COMPILES_AFTER_WARM_UP], capture_output=True, text=True,
        check=True, timeout=600,
    )  # fmt: skip
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_a_failure_half_way_keeps_what_was_computed(short_drive, tmp_path):
    scans, _ = short_drive

    def failing():
        yield from scans[:40]
        raise OSError("disk went away")

    result = run_slam(failing(), options=RunOptions(progress=False))
    assert result.error == "OSError: disk went away"
    summary = write_results(result, tmp_path)
    assert summary["error"] == "OSError: disk went away"
    assert len(read_tum(tmp_path / "trajectory.tum")) == 40
    assert len(read_uncertainty(tmp_path / "odometry_uncertainty.csv")) == 40



@pytest.mark.parametrize("odometry_only", [False, True])
def test_a_signal_between_a_scans_column_appends_leaves_whole_scans(
    short_drive, tmp_path, odometry_only, monkeypatch
):
    """The scan loop can be interrupted anywhere, also half-way through recording a scan:
    what is written then holds the scans recorded whole, every file the same length."""
    from bioslam.slam import MatchUncertainty

    scans, _ = short_drive
    calls = {"n": 0}
    append = MatchUncertainty.append

    def interrupted_on_the_31st(self, report):
        calls["n"] += 1
        if calls["n"] == 31:
            raise KeyboardInterrupt
        append(self, report)

    monkeypatch.setattr(MatchUncertainty, "append", interrupted_on_the_31st)
    options = RunOptions(progress=False, warm_up=False, odometry_only=odometry_only)
    result = run_slam(scans[:60], options=options)
    assert result.interrupted
    write_results(result, tmp_path, options=options)
    assert len(read_tum(tmp_path / "trajectory.tum")) == 30
    assert len(read_tum(tmp_path / "odometry.tum")) == 30
    assert len(read_uncertainty(tmp_path / "odometry_uncertainty.csv")) == 30


@pytest.mark.parametrize("odometry_only", [False, True])
def test_a_run_with_a_store_directory_keeps_its_per_scan_columns_there(
    short_drive, tmp_path, odometry_only
):
    """With ``scan_store_dir`` the per-scan columns and timings go to files there
    (bioslam.io.spill.SpilledRows) and the written trajectories are byte for byte those of
    a run that keeps them in memory."""
    from bioslam.io.spill import SpilledRows

    scans, _ = short_drive
    scans = scans[:150]
    written = {}
    for name, store in (("memory", None), ("disk", tmp_path / "store")):
        if store is not None:
            store.mkdir()
        options = RunOptions(progress=False, warm_up=False, odometry_only=odometry_only,
                             scan_store_dir=store, release=True)  # fmt: skip
        result = run_slam(scans, options=options)
        assert isinstance(result.scan_seconds, SpilledRows) == (store is not None)
        assert len(result.scan_seconds) == len(scans)
        write_results(result, tmp_path / name, options=options)
        files = ("trajectory.tum", "odometry.tum", "odometry_uncertainty.csv")
        written[name] = [(tmp_path / name / f).read_bytes() for f in files]
    assert written["disk"] == written["memory"]
    assert len(written["disk"][0].splitlines()) >= len(scans)

def test_odometry_only_mode(short_drive, tmp_path):
    scans, _ = short_drive
    options = RunOptions(progress=False, odometry_only=True)
    summary = write_results(run_slam(scans, options=options), tmp_path, options=options)
    assert summary["experiences"] == 0
    a, b = read_tum(tmp_path / "trajectory.tum"), read_tum(tmp_path / "odometry.tum")
    assert np.allclose(a.poses, b.poses)
    assert len(read_uncertainty(tmp_path / "odometry_uncertainty.csv")) == len(scans)


def test_run_command_on_a_simulated_bag(tmp_path, capsys):
    # the 360-degree preset: the 240-degree, 5.6 m URG-04LX loses track in the maze's long
    # corridors (benchmarks/bench_odometry.py, case shortrange)
    sim = tmp_path / "sim"
    assert main(["sim", "--lidar", "rplidar", "--duration", "17", "--seed", "2",
                 "--out", str(sim)]) == 0
    capsys.readouterr()
    out = tmp_path / "run"
    assert main(["run", str(sim / "scans"), "--out", str(out), "--gt", str(sim / "gt.tum"),
                 "--no-progress"]) == 0
    summary = last_json(capsys)
    assert set(summary) >= RUN_KEYS | EVAL_KEYS
    assert summary["format"] == "rosbag2" and summary["scans"] == 119
    assert summary["ate_rmse_m"] < 0.05


def test_run_command_reports_a_missing_input(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.bag"), "--out", str(tmp_path / "o")]) == 2
    assert "nope.bag" in capsys.readouterr().err


def test_demo_writes_the_papers_figures(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--duration", "15", "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    summary = json.loads(text.strip().splitlines()[-1])
    assert "mean position error" in text and "2.84 cm" in text
    assert set(summary) >= RUN_KEYS | EVAL_KEYS
    assert summary["scans"] == 600
    for name in ("gt.tum", "trajectory.tum", "world.png", "figures/mapping_progress.png",
                 "figures/views_and_error.png"):
        assert (out / name).exists()


@pytest.mark.skipif(not hasattr(os, "fork"), reason="the figure worker forks")
def test_figures_drawn_by_a_worker_are_those_drawn_here(short_drive, tmp_path, monkeypatch):
    from bioslam.plots import figures
    from bioslam.plots.worker import FigureWorker

    scans, gt = short_drive
    end = float(gt.stamps[-1] - gt.stamps[0])
    result = run_slam(scans, options=RunOptions(progress=False, snapshot_times=(5.0, end)))

    def written(folder, broken: bool = False) -> tuple[dict, dict]:
        with FigureWorker() as worker:  # forked after the patch below: the child has it too
            options = RunOptions(progress=False, figure_worker=worker)
            summary = write_results(result, tmp_path / folder, gt, options)
        files = {p.name: p.read_bytes() for p in (tmp_path / folder / "figures").iterdir()}
        here = write_results(result, tmp_path / f"{folder}-here", gt, RunOptions(progress=False))
        assert here.get("figures_error") == summary.get("figures_error")
        assert files == {p.name: p.read_bytes()
                         for p in (tmp_path / f"{folder}-here" / "figures").iterdir()}
        return summary, files

    summary, files = written("worker")
    assert "figures_error" not in summary
    assert set(files) == {"map.png", "cognitive_map.png", "active_view.png", "error.png",
                          "views_and_error.png", "mapping_progress.png"}

    def refuse(*args, **kwargs):
        raise ValueError("no views to draw")

    monkeypatch.setattr(figures, "plot_active_view", refuse)
    summary, files = written("broken")  # the figures before the failing one are kept
    assert summary["figures_error"] == "ValueError: no views to draw"
    assert set(files) == {"map.png", "cognitive_map.png"}


def test_every_closure_check_is_written_and_judged_against_the_reference(tmp_path):
    route = ring_route(laps=1.6)
    pairs = list(simulate_scans(ring_world(), LIDAR_PRESETS["urg04lx"], route, seed=3))
    scans = [s for s, _ in pairs]
    gt = Trajectory(np.array([s.stamp for s in scans]), np.array([p for _, p in pairs]))
    options = RunOptions(progress=False)
    result = run_slam(scans, options=options)
    summary = write_results(result, tmp_path / "true", gt, options)
    rows = read_closures(tmp_path / "true" / "closures.csv")
    assert len(rows) == len(result.system.checks) > 0
    accepted = [r for r in rows if r["accepted"] == "1"]
    assert len(accepted) == summary["loop_closures"] >= 3
    assert summary["loop_closures_against_reference"] == len(accepted)
    assert summary["loop_closures_off_reference"] == 0
    assert all(float(r["reference_error_m"]) < 0.1 for r in accepted)
    assert all(float(r["odometry_reference_error_m"]) < 0.1 for r in accepted)
    assert summary["loop_closure_odometry_reference_error_median_m"] < 0.05
    assert all(r["reason"] for r in rows if r["accepted"] == "0")
    # A reference that jumps 1 m sideways half-way: the closures across the jump now
    # disagree with it by 1 m, and are counted off it; the others still agree.
    half = 0.5 * (gt.stamps[0] + gt.stamps[-1])
    shifted = gt.poses.copy()
    shifted[gt.stamps >= half, 1] += 1.0
    summary = write_results(result, tmp_path / "off", Trajectory(gt.stamps, shifted), options)
    accepted = [r for r in read_closures(tmp_path / "off" / "closures.csv") if r["accepted"] == "1"]
    across = [r for r in accepted if float(r["experience_stamp"]) < half <= float(r["stamp"])]
    assert 0 < len(across) < len(accepted)
    assert summary["loop_closures_off_reference"] == len(across)
    # ... and so does the odometry between the same stamps: the reference is what is off
    for row in across:
        assert float(row["reference_error_m"]) == pytest.approx(1.0, abs=0.1)
        assert float(row["odometry_reference_error_m"]) == pytest.approx(1.0, abs=0.1)
    assert all(float(r["odometry_reference_error_m"]) < 0.1 for r in accepted if r not in across)
    # without a reference, or with one the run cannot be evaluated against (its stamps out
    # of order), the table has no reference columns
    backwards = Trajectory(gt.stamps[::-1].copy(), gt.poses[::-1].copy())
    for name, reference in (("none", None), ("backwards", backwards)):
        summary = write_results(result, tmp_path / name, reference, options)
        header = (tmp_path / name / "closures.csv").read_text().splitlines()[0]
        assert "reference_error_m" not in header and header.startswith("stamp,experience,")
        assert "loop_closures_off_reference" not in summary
        assert "loop_closure_odometry_reference_error_median_m" not in summary
    assert "evaluation_error" in summary


def test_a_check_refused_before_its_registration_leaves_its_score_empty(tmp_path):
    unregistered = Verdict(False, np.array([1.0, -2.0, 0.5]), float("nan"), 0.0, "beyond drift")
    refused = Check(12.5, 7, 3.25, "proximity", unregistered)
    accepted = Check(13.0, 7, 3.25, "view", Verdict(True, np.array([0.1, 0.2, -0.1]), 0.93, 0.4))
    errors = np.array([[np.nan, np.nan], [0.02, 1.5]])
    write_closures(tmp_path / "c.csv", [refused, accepted], errors)
    first, second = read_closures(tmp_path / "c.csv")
    assert (first["accepted"], first["reason"], first["score"]) == ("0", "beyond drift", "")
    assert first["reference_error_m"] == "" and float(first["theta_deg"]) == pytest.approx(28.648)
    assert (second["accepted"], second["reason"], second["score"]) == ("1", "", "0.9300")
    assert float(second["reference_error_deg"]) == pytest.approx(1.5)


def test_a_logs_corrected_poses_are_drawn_as_a_reference_not_as_ground_truth(
    short_drive, tmp_path, monkeypatch, capsys
):
    """A log's corrected poses are another SLAM system's estimate: the figures that draw them
    or the errors against them say so; a simulation's poses (or ``--gt``) are the truth."""
    from _log_fixtures import carmen_text

    from bioslam.plots import GROUND_TRUTH, LOG_REFERENCE, figures

    drawn: dict[str, list[str]] = {}
    against = ("plot_cognitive_map", "plot_error_over_time", "plot_views_and_errors",
               "plot_mapping_progress")  # fmt: skip
    def recording(name):
        plot = getattr(figures, name)

        def record(*args, **kwargs):
            drawn.setdefault(name, []).append(args[-1])  # the label: the jobs' last argument
            return plot(*args, **kwargs)

        return record

    for name in against:
        monkeypatch.setattr(figures, name, recording(name))
    scans, gt = short_drive
    end = float(gt.stamps[-1] - gt.stamps[0])
    result = run_slam(scans, options=RunOptions(progress=False, snapshot_times=(5.0, end)))
    write_results(result, tmp_path / "sim", gt, RunOptions(progress=False))
    assert drawn == {name: [GROUND_TRUTH] for name in against}
    drawn.clear()
    log = tmp_path / "robot-corrected.log"  # named as the Radish data sets' corrected logs
    log.write_text(carmen_text(scans=40), encoding="latin-1")
    assert main(["run", str(log), "--out", str(tmp_path / "log"), "--no-progress",
                 "--one-process"]) == 0  # fmt: skip
    assert (tmp_path / "log" / "reference.tum").is_file()
    assert drawn["plot_cognitive_map"] == [LOG_REFERENCE]
    assert drawn["plot_error_over_time"] == [LOG_REFERENCE]
