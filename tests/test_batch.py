"""``bioslam batch``: grid expansion, the results table, resume, failures and Ctrl-C, and the
same rows from the local process pool and from Ray."""

from __future__ import annotations

import shutil
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bioslam.batch import BatchSpec, expand_grid, run_batch
from bioslam.batch.engines import ProcessEngine, make_engine
from bioslam.batch.results import MACHINE_COLUMNS, read_csv
from bioslam.batch.runner import DONE_MARKER, finished_row, log_names, plan
from bioslam.batch.task import Files, Outcome, Task, pack, run_task, unpack
from bioslam.cli import main
from bioslam.io.bag_writer import write_scan_bag
from bioslam.io.tum import write_tum
from bioslam.sim import LIDAR_PRESETS, make_route, maze_world, simulate_scans
from bioslam.trajectory import Trajectory

GRID = {"mode": "odometry-only", "odometry.resolution": [0.03, 0.06]}


def simulated_log(folder: Path, seed: int) -> Path:
    """A 4 s drive through the maze (URG-04LX, 5 % dropouts) as a ROS 2 bag with gt.tum."""
    world = maze_world()
    route = make_route(world, duration=4.0, seed=seed)
    lidar = replace(LIDAR_PRESETS["urg04lx"], dropout_prob=0.05)
    pairs = list(simulate_scans(world, lidar, route, seed=seed))
    write_scan_bag(folder / "scans", [s for s, _ in pairs], scan_time=lidar.scan_time)
    stamps = np.array([s.stamp for s, _ in pairs])
    write_tum(folder / "gt.tum", Trajectory(stamps, np.array([p for _, p in pairs])))
    return folder / "scans"


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> list[Path]:
    """Two simulated bags, both named ``scans``, and a file no reader understands."""
    root = tmp_path_factory.mktemp("logs")
    bags = [simulated_log(root / f"drive{seed}", seed) for seed in (3, 4)]
    broken = root / "broken.txt"
    broken.write_text("this is not a LiDAR log\n")
    return [*bags, broken]


def spec(logs: Sequence[Path], out: Path, ship: bool = False) -> BatchSpec:
    return BatchSpec(logs, out, expand_grid(GRID), gt_from="{dir}/gt.tum", ship_data=ship)


@pytest.fixture(scope="module")
def pool_batch(logs, tmp_path_factory):
    out = tmp_path_factory.mktemp("pool") / "batch"
    report = run_batch(spec(logs, out), ProcessEngine(2), progress=False)
    return out, report


def without_machine_columns(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in MACHINE_COLUMNS} for row in rows]


def test_grid_expands_dotted_keys_tables_and_fixed_values():
    points = expand_grid({
        "mode": ["full", "odometry-only"],
        "odometry": {"resolution": [0.03, 0.05]},
        "views.s_t": 0.4,
    })
    assert [p.config_id for p in points] == [
        "mode=full,odometry.resolution=0.03", "mode=full,odometry.resolution=0.05",
        "mode=odometry-only,odometry.resolution=0.03",
        "mode=odometry-only,odometry.resolution=0.05",
    ]
    last = points[-1]
    assert last.mode == "odometry-only"
    config = last.config()
    assert config.odometry.resolution == 0.05 and config.views.s_t == 0.4
    assert last.varying == ("mode", "odometry.resolution")


def test_grid_rejects_what_no_run_could_use():
    with pytest.raises(ValueError, match=r"unknown setting 'odometry\.resolutoin'"):
        expand_grid({"odometry.resolutoin": [0.03, 0.05]})
    with pytest.raises(ValueError, match="mode must be one of"):
        expand_grid({"mode": ["fast"]})
    with pytest.raises(ValueError, match="empty list"):
        expand_grid({"odometry.resolution": []})
    with pytest.raises(ValueError, match="max_scans"):
        expand_grid({"max_scans": [0, 100]})


def test_logs_of_the_same_name_get_distinct_folders(tmp_path):
    paths = [tmp_path / "a" / "scans", tmp_path / "b" / "scans", tmp_path / "c.log.gz"]
    assert log_names(paths) == ["a-scans", "b-scans", "c"]
    with pytest.raises(ValueError, match="twice"):
        log_names([paths[0], paths[0]])


def test_shipped_files_stay_inside_their_folder(tmp_path, logs):
    files = pack(logs[0])
    assert sorted(files) == sorted(
        str(Path("scans") / p.relative_to(logs[0])) for p in logs[0].rglob("*") if p.is_file()
    )
    unpack(files, tmp_path / "copy")
    assert (tmp_path / "copy" / "scans" / "metadata.yaml").is_file()
    with pytest.raises(ValueError, match="outside"):
        unpack({"../evil": b"x"}, tmp_path / "copy")


def test_a_pool_batch_writes_rows_outputs_and_markers(pool_batch):
    out, report = pool_batch
    assert (report.runs, report.ok, report.failed, report.skipped) == (6, 4, 2, 0)
    rows = read_csv(out / "results.csv")
    assert [(r["log"], r["config"]) for r in rows] == [
        (log, f"odometry.resolution={res}")
        for log in ("drive3-scans", "drive4-scans", "broken") for res in (0.03, 0.06)
    ]
    for row in rows[:4]:
        assert row["status"] == "ok" and row["error"] == ""
        assert row["reference"].endswith("gt.tum")
        # evaluated against the drive's own ground truth: a ~2 m drive, so an association
        # with the wrong file or frame would give errors of metres
        assert 0.0 < float(row["ate_rmse_m"]) < 0.3
        assert float(row["peak_rss_mb"]) > 10
        run = out / row["log"] / row["config"]
        assert (run / "trajectory.tum").is_file() and (run / DONE_MARKER).is_file()
    for row in rows[4:]:
        assert row["status"] == "failed" and "unknown log format" in row["error"]
        assert not (out / "broken" / row["config"] / DONE_MARKER).exists()
    text = (out / "results.md").read_text()
    assert "## Best configuration per metric" in text and "2 failed" in text


@pytest.fixture
def ray_shut_down_after():
    """Ray stays down after the test whatever happens in it (the engine starts its own local
    instance, 2 CPUs, no dashboard)."""
    ray = pytest.importorskip("ray", reason="Ray is an optional extra: pip install 'bioslam[ray]'")
    yield
    ray.shutdown()


def test_ray_gives_the_same_rows_as_the_pool(pool_batch, logs, tmp_path, ray_shut_down_after):
    out, _ = pool_batch
    engine = make_engine("ray", 2)
    # logs shipped through the object store and outputs sent back as bytes
    report = run_batch(spec(logs, tmp_path / "ray", ship=True), engine, progress=False)
    assert report.ok == 4
    expected = without_machine_columns(read_csv(out / "results.csv"))
    assert without_machine_columns(read_csv(tmp_path / "ray" / "results.csv")) == expected
    shipped_back = tmp_path / "ray" / "drive4-scans" / "odometry.resolution=0.06"
    assert (shipped_back / "odometry.tum").is_file()


def test_a_rerun_skips_finished_runs_and_retries_the_rest(pool_batch, logs, tmp_path):
    first, _ = pool_batch
    out = tmp_path / "batch"
    shutil.copytree(first, out)
    unfinished = out / "drive4-scans" / "odometry.resolution=0.03"
    (unfinished / DONE_MARKER).unlink()  # as if the batch had stopped during this run
    stale = unfinished / "left-over.txt"
    stale.write_text("from an earlier attempt")
    finished = out / "drive3-scans" / "odometry.resolution=0.03" / DONE_MARKER
    before = finished.stat().st_mtime_ns
    report = run_batch(spec(logs, out), ProcessEngine(1), progress=False)
    assert (report.skipped, report.ok, report.failed) == (3, 4, 2)
    assert finished.stat().st_mtime_ns == before
    assert not stale.exists() and (unfinished / DONE_MARKER).is_file()
    assert without_machine_columns(read_csv(out / "results.csv")) == without_machine_columns(
        read_csv(first / "results.csv")
    )
    # a run is finished for its log, settings and ground truth: another --gt-from reruns it
    task = plan(spec(logs, out))[0]
    assert finished_row(task)["ate_rmse_m"] is not None
    assert finished_row(replace(task, reference=None, reference_name=None)) is None
    assert finished_row(replace(task, point=expand_grid({"odometry.resolution": 0.04})[0])) is None


class InterruptedEngine:
    """Runs tasks in this process and gets Ctrl-C after the first one."""

    workers = 1

    def __init__(self) -> None:
        self.stopped = False

    def run(self, tasks: Sequence[Task], shipped: dict[str, Files] | None) -> Iterator[Outcome]:
        yield run_task(tasks[0])
        raise KeyboardInterrupt

    def stop(self) -> None:
        self.stopped = True


def test_ctrl_c_keeps_finished_rows_and_the_next_run_goes_on(logs, tmp_path):
    engine = InterruptedEngine()
    out = tmp_path / "batch"
    report = run_batch(spec(logs[:1], out), engine, progress=False)
    assert report.interrupted and engine.stopped
    rows = read_csv(out / "results.csv")
    assert len(rows) == 1 and rows[0]["status"] == "ok"
    assert "interrupted" in (out / "results.md").read_text()
    again = run_batch(spec(logs[:1], out), InterruptedEngine(), progress=False)
    assert again.skipped == 1 and len(read_csv(out / "results.csv")) == 2


def test_the_command_refuses_a_folder_it_did_not_write(logs, tmp_path, capsys):
    (tmp_path / "mine.txt").write_text("keep me")
    code = main(["batch", str(logs[0]), "--out", str(tmp_path), "--engine", "process"])
    assert code != 0
    assert "not a batch output folder" in capsys.readouterr().err
    assert (tmp_path / "mine.txt").read_text() == "keep me"


def test_shipped_data_gives_the_run_a_shared_path_gives(logs, tmp_path):
    point = expand_grid({"mode": "odometry-only", "max_scans": 12})[0]
    task = Task("drive3-scans", str(logs[0]), point, str(tmp_path / "shared"))
    in_place = run_task(task)
    shipped = run_task(task, pack(logs[0]))
    assert in_place.status == shipped.status == "ok"
    assert in_place.summary["scans"] == shipped.summary["scans"] == 12  # max_scans is a prefix
    assert shipped.files is not None and "trajectory.tum" in shipped.files
    assert shipped.files["trajectory.tum"] == (tmp_path / "shared" / "trajectory.tum").read_bytes()
    assert shipped.peak_rss_mb > 10
