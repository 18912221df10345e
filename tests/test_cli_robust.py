"""The commands on bad input and in bad conditions: exit codes, the end-of-run report, the
output directory's marker and policy, atomic outputs, configs checked by key, strict JSON."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from _cli_logs import write_carmen

from bioslam.cli import main
from bioslam.config import config_from_dict, load_config
from bioslam.io.outdir import MARKER, OutputDir, check_output_dir, remove_previous_run
from bioslam.io.tum import read_tum, write_tum
from bioslam.trajectory import Trajectory

SRC = Path(__file__).resolve().parents[1] / "src"


def strict_json(text: str):
    """Parse JSON refusing NaN/Infinity, as strict parsers (and other languages) do."""
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


def last_json(out: str):
    return strict_json(out.strip().splitlines()[-1])


@pytest.fixture(autouse=True)
def _no_warm_up(monkeypatch):
    """The warm-up only fills Numba's cache; it is tested in test_pipeline."""
    monkeypatch.setattr("bioslam.pipeline.warm_up", lambda *a, **k: 0.0)


@pytest.fixture
def log(tmp_path):
    return write_carmen(tmp_path / "room.log", scans=30)


def run(capsys, *argv):
    code = main(["run", *map(str, argv), "--no-progress"])
    out, err = capsys.readouterr()
    return code, out, err


# --- reading: the end-of-run report and the share read ------------------------------------


def test_a_partial_read_fails_unless_accepted(tmp_path, capsys):
    log = write_carmen(tmp_path / "half.log", scans=30, bad=set(range(0, 30, 3)))
    code, out, err = run(capsys, log, "--out", tmp_path / "a", "--odometry-only")
    assert code == 1
    assert "read 20 of 30 scan records" in err
    assert "skipped 10 x wrong beam count (first: line 1" in err
    assert "--accept-partial" in err and "66.7 %" in err
    summary = last_json(out)
    assert summary["scans"] == 20 and summary["read_share"] == pytest.approx(2 / 3, abs=1e-4)
    assert len(read_tum(tmp_path / "a" / "trajectory.tum")) == 20  # written all the same
    code, _, _ = run(capsys, log, "--out", tmp_path / "b", "--odometry-only",
                     "--accept-partial")
    assert code == 0
    code, _, _ = run(capsys, log, "--out", tmp_path / "c", "--odometry-only",
                     "--min-read-share", "0.6")
    assert code == 0


def test_a_log_with_unusable_stamps_runs_whole_and_says_where_its_time_came_from(
    tmp_path, capsys
):
    clean = write_carmen(tmp_path / "clean.log", scans=30)
    zeroed = tmp_path / "zeroed.log"
    zeroed.write_text("".join(
        " ".join([*line.split()[:-3], "0.000000", "host", "0.000000"]) + "\n"
        for line in clean.read_text().splitlines()
    ))
    code, out, err = run(capsys, zeroed, "--out", tmp_path / "z", "--odometry-only")
    assert code == 0, err
    summary = last_json(out)
    assert summary["scans"] == 30 and summary["read_share"] == 1.0
    assert summary["time_source"].startswith("record order"), summary["time_source"]
    assert "record order" in err
    code, out, _ = run(capsys, clean, "--out", tmp_path / "c", "--odometry-only")
    assert code == 0 and last_json(out)["time_source"] == "log stamps"


def test_a_run_of_zero_scans_fails(tmp_path, capsys):
    log = tmp_path / "junk.log"
    log.write_bytes(b"FLASER 3 1 2\n" * 5)  # a CARMEN log whose every scan is malformed
    code, out, err = run(capsys, log, "--out", tmp_path / "o", "--accept-partial")
    assert code == 1
    assert "0 scans processed" in err
    assert last_json(out)["scans"] == 0


@pytest.mark.parametrize("content", [os.urandom(3000), b""])
def test_a_file_that_is_no_log_is_an_input_error(tmp_path, capsys, content):
    log = tmp_path / "junk.log"
    log.write_bytes(content)
    code, _, err = run(capsys, log, "--out", tmp_path / "o", "--accept-partial")
    assert code == 2  # refused before the run: the content is no supported format
    assert str(log) in err and "Traceback" not in err


# --- checks before the run ------------------------------------------------------------------


def test_bad_inputs_are_refused_before_anything_is_written(tmp_path, capsys, log):
    bad_gt = tmp_path / "gt.tum"
    bad_gt.write_text("1 0 0 0 0 0 0 1\n2 0 0 nan 0 0 0 1\n")
    bad_config = tmp_path / "c.toml"
    bad_config.write_text("[odometry]\nresolution = 'fine'\n")
    out = tmp_path / "o"
    cases = [
        (["--gt", bad_gt], "gt.tum:2: value not finite"),
        (["--config", bad_config], "c.toml: odometry.resolution = \"fine\": expected a number"),
        (["--config", tmp_path / "missing.toml"], "missing.toml"),
        (["--gt", tmp_path], "no such file"),
    ]
    for extra, message in cases:
        code, stdout, err = run(capsys, log, "--out", out, *extra)
        assert code == 2 and message in err and stdout == ""
        assert not out.exists()
    code, _, err = run(capsys, tmp_path / "none.log", "--out", out)
    assert code == 2 and "none.log" in err and not out.exists()


def test_out_that_is_a_file_or_unwritable_is_refused(tmp_path, capsys, log):
    code, _, err = run(capsys, log, "--out", log)
    assert code == 2 and "is a file" in err
    code, _, err = run(capsys, log, "--out", "/proc/bioslam-out")
    assert code == 2 and "cannot write" in err


def test_not_enough_free_space_is_refused(tmp_path):
    with pytest.raises(ValueError, match="MB free"):
        check_output_dir(tmp_path / "o", overwrite=False, needed_bytes=2**62)


# --- the output directory -------------------------------------------------------------------


def test_rerun_needs_overwrite_which_removes_only_the_previous_runs_files(
    tmp_path, capsys, log
):
    out = tmp_path / "o"
    assert run(capsys, log, "--out", out)[0] == 0
    marker = json.loads((out / MARKER).read_text())
    assert marker["status"] == "complete" and marker["command"][:2] == ["bioslam", "run"]
    assert sorted(marker["files"]) == sorted(
        str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and p.name != MARKER
    )
    code, _, err = run(capsys, log, "--out", out)
    assert code == 2 and "--overwrite" in err
    (out / "notes.txt").write_text("mine")
    (out / "figures" / "extra.png").write_bytes(b"mine")
    (out / "figures" / "error.png").write_bytes(b"stale")  # a figure this run will not draw
    marker["files"].append("figures/error.png")
    marker["files"].append("../outside.txt")  # never followed out of the directory
    (tmp_path / "outside.txt").write_text("keep")
    (out / MARKER).write_text(json.dumps(marker))
    assert run(capsys, log, "--out", out, "--overwrite", "--odometry-only")[0] == 0
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "figures" / "extra.png").exists()
    assert not (out / "figures" / "error.png").exists()
    assert not (out / "cognitive_map.json").exists()  # the old run's, not written by this one
    assert (tmp_path / "outside.txt").exists()


def test_a_directory_of_other_files_is_refused(tmp_path, capsys, log):
    out = tmp_path / "o"
    out.mkdir()
    (out / "data.csv").write_text("1,2\n")
    code, _, err = run(capsys, log, "--out", out)
    assert code == 2 and "other files" in err
    assert remove_previous_run(out) == [] and (out / "data.csv").exists()


def test_an_unreadable_marker_is_not_guessed_at(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / MARKER).write_text("{not json")
    with pytest.raises(ValueError, match="unreadable marker"):
        check_output_dir(out, overwrite=True, needed_bytes=0)


def test_a_failed_write_names_the_file_and_the_others_are_written(tmp_path):
    out = OutputDir(tmp_path / "o")
    out.prepare()

    def full_disk():
        raise OSError(28, "No space left on device")

    assert not out.write("trajectory.tum", full_disk)
    assert out.save("odometry.tum", write_tum, Trajectory.empty())
    assert out.errors == [f"{tmp_path / 'o' / 'trajectory.tum'}: No space left on device"]
    assert json.loads((tmp_path / "o" / MARKER).read_text())["files"] == ["odometry.tum"]


def _limit_file_size():
    # A file-size limit makes big writes fail with EFBIG like a full disk would (SIGXFSZ
    # ignored so that the write returns an error instead of killing the process).
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))


def test_full_disk_leaves_no_half_written_file(tmp_path):
    log = write_carmen(tmp_path / "room.log", scans=260)  # trajectory.tum ~ 26 kB
    out = tmp_path / "o"
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    command = [sys.executable, "-m", "bioslam.cli", "run", str(log), "--no-progress",
               "--odometry-only", "--out"]  # fmt: skip
    # once without the limit, so that the kernels' compiled cache is written: the limited
    # run is to fail on its results, not on a cache the tests before it left unwritten
    subprocess.run([*command, str(tmp_path / "warm")], capture_output=True, env=env, timeout=300)
    proc = subprocess.run(
        [*command, str(out)],
        capture_output=True, text=True, env=env, preexec_fn=_limit_file_size, timeout=300,
    )
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert f"{out / 'trajectory.tum'}: File too large" in proc.stderr
    assert not (out / "trajectory.tum").exists() and not (out / "odometry.tum").exists()
    assert not [p for p in out.rglob("*.tmp*")]
    summary = strict_json((out / "summary.json").read_text())
    assert summary["scans"] == 260
    failed = [Path(e.split(": ")[0]) for e in summary["write_errors"]]
    assert {out / "trajectory.tum", out / "odometry.tum"} <= set(failed)
    assert not any(p.exists() for p in failed)  # the big files: none half-written
    assert "summary.json" in json.loads((out / MARKER).read_text())["files"]


# --- configuration --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"odometry": {"resolution": "fine"}}', 'odometry.resolution = "fine": expected a number'),
        ('{"odometry": 3}', "odometry must be a table"),
        ("[1, 2]", "the top level must be a table"),
        ('{"views": {"ds": true}}', "views.ds = true: expected a number"),
        ('{"odometry": {"resolution": 1e-9}}', "odometry.resolution = 1e-09: must be in"),
        ('{"odometry": {"resolution": 0.001, "map_size": 9000}}', "would not fit in memory"),
        ('{"odometry": {"levls": 2}}', "unknown setting 'odometry.levls'"),
        ('{"odometry": {"levels": 2.5}}', "odometry.levels = 2.5: expected an integer"),
        ('{"odometry": {"max_iterations": [3, "x"]}}', "odometry.max_iterations[1]"),
        ('{"pose_cells": {"dims": [21, 21]}}', "pose_cells.dims = [21, 21]: expected 3 values"),
        ('{"view_distance": -1}', "view_distance = -1: must not be negative"),
        ('{"loop_closure": {"min_score": NaN}}', "expected a finite number"),
        ('{"odometry": {"deskew": 1}}', "odometry.deskew = 1: expected true or false"),
        ('{"cognitive_map": {"sweeps_per_update": 1e12}}', "expected an integer"),
        ('{"cognitive_map": {"sweeps_per_update": 1000000000000}}', "must be at most"),
        ('{"pose_cells": {"dims": [1000, 1000, 36]}}', "pose_cells.dims asks for a grid"),
    ],
)
def test_config_errors_name_the_file_and_the_key(tmp_path, text, message):
    path = tmp_path / "c.json"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value)


def test_config_accepts_what_toml_users_write():
    config = config_from_dict({"odometry": {"resolution": 1, "max_iterations": [5, 5, 5]},
                               "heading_bias": -0.001, "cognitive_map": {"solve_window": None}})
    assert config.odometry.resolution == 1.0 and isinstance(config.odometry.resolution, float)
    assert config.odometry.max_iterations == (5, 5, 5)
    assert config.heading_bias == -0.001 and config.cognitive_map.solve_window is None


# --- eval -----------------------------------------------------------------------------------


def _line(t, x):
    return f"{t} {x} 0 0 0 0 0 1\n"


def test_eval_refuses_too_few_pairs_and_non_finite_poses(tmp_path, capsys):
    a, b = tmp_path / "a.tum", tmp_path / "b.tum"
    a.write_text("".join(_line(k, k) for k in range(20)))
    b.write_text("".join(_line(k + 0.5, k) for k in range(20)) + _line(3.0 + 20, 1))
    assert main(["eval", str(a), str(b)]) == 2
    err = capsys.readouterr().err
    assert "only 0 associated poses" in err or "no matching stamps" in err
    b.write_text("".join(_line(k, k) for k in range(3)))
    assert main(["eval", str(a), str(b)]) == 2
    assert "only 3 associated poses" in capsys.readouterr().err
    assert main(["eval", str(a), str(b), "--min-pairs", "3"]) == 0
    last_json(capsys.readouterr().out)
    b.write_text("".join(_line(k, k) for k in range(5)) + "5 inf 0 0 0 0 0 1\n")
    assert main(["eval", str(a), str(b)]) == 2
    assert "b.tum:6: value not finite" in capsys.readouterr().err


def test_tum_reader_names_the_line_of_each_defect(tmp_path):
    path = tmp_path / "t.tum"
    for body, message in [
        (_line(1, 0) + "2 0 0 0 0 0 0\n", "t.tum:2: expected 8 fields"),
        (_line(1, 0) + _line(1, 0), "t.tum:2: stamp 1.000000000 s is not later"),
        ("# c\n" + _line(1, 0) + "2 0 0 0 0 0 0 x\n", "t.tum:3: could not convert"),
        ("1 0 0 0 0 0 0 0\n", "t.tum:1: zero quaternion"),
        ("nan 0 0 0 0 0 0 1\n", "t.tum:1: value not finite"),
    ]:
        path.write_text(body)
        with pytest.raises(ValueError, match=message):
            read_tum(path)
