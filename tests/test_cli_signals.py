"""SIGINT and SIGTERM sent to ``bioslam run`` at chosen and at random moments: the command stops
cleanly, writes what it computed with ``"interrupted": true``, exits 128 + the signal number and
never prints a traceback. Children run in parallel to keep the suite short."""

from __future__ import annotations

import json
import math
import os
import random
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from _cli_logs import write_carmen

from bioslam.io.outdir import MARKER
from bioslam.io.tum import read_tum

SRC = Path(__file__).resolve().parents[1] / "src"
pytestmark = pytest.mark.skipif(
    not Path("/proc/self/status").exists(), reason="needs Linux /proc to see signal handlers"
)


def strict_json(text: str):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


class Child:
    """A ``bioslam run`` child whose stderr is collected as it comes."""

    def __init__(self, log: Path | None, out: Path, *extra: str) -> None:
        self.out = out
        env = {**os.environ, "PYTHONPATH": str(SRC)}
        argv = ["run", str(log), "--out", str(out)] if log is not None else []
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bioslam.cli", *argv, *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
        )
        self.err = ""
        self._out = b""
        self._readers = [threading.Thread(target=self._read_err, daemon=True),
                         threading.Thread(target=self._read_out, daemon=True)]
        for reader in self._readers:
            reader.start()
        self.signum: int | None = None

    def _read_err(self) -> None:
        for chunk in iter(lambda: self.proc.stderr.read1(4096), b""):
            self.err += chunk.decode(errors="replace")

    def _read_out(self) -> None:
        self._out = self.proc.stdout.read()

    def handlers_installed(self) -> bool:
        """True once the command handles SIGTERM (Python itself only catches SIGINT)."""
        try:
            status = Path(f"/proc/{self.proc.pid}/status").read_text()
        except OSError:
            return False
        caught = int(re.search(r"SigCgt:\s*([0-9a-f]+)", status).group(1), 16)
        return bool(caught >> (signal.SIGTERM - 1) & 1)

    def cpu_seconds(self) -> float:
        """CPU time the child has used (on a shared machine, a better clock of how far it
        got than wall time)."""
        try:
            stat = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            return math.inf
        return (int(stat[11]) + int(stat[12])) / os.sysconf("SC_CLK_TCK")

    def marker(self) -> dict | None:
        try:
            return json.loads((self.out / MARKER).read_text())
        except (OSError, ValueError):
            return None

    def processing(self) -> bool:
        counts = re.findall(r"(?:^|\r)(\d+)scan \[", self.err, flags=re.M)
        return bool(counts) and int(counts[-1]) >= 5

    def send(self, signum: int) -> None:
        if self.proc.poll() is None:
            self.signum = signum
            self.proc.send_signal(signum)

    def finish(self) -> tuple[int, str]:
        self.proc.wait(timeout=300)
        for reader in self._readers:
            reader.join(timeout=10)
        return self.proc.returncode, self._out.decode()


def wait_for(condition, timeout: float = 300.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError("the child never reached the moment to signal it")
        time.sleep(0.005)


def check_outcome(child: Child, total_scans: int) -> dict | None:
    """What every interrupted (or finished) run must satisfy; returns its summary."""
    code, stdout = child.finish()
    assert "Traceback" not in child.err, child.err
    interrupted_code = 128 + child.signum if child.signum else None
    assert code in (0, interrupted_code), (code, child.err)
    marker = child.marker()
    if marker is None:  # stopped before the output directory was made: nothing written
        assert code == interrupted_code and stdout == ""
        return None
    assert [p for p in child.out.rglob("*.tmp*")] == []
    for name in marker["files"]:
        assert (child.out / name).is_file(), name
    summary = strict_json((child.out / "summary.json").read_text())
    assert strict_json(stdout.strip().splitlines()[-1]) == summary
    trajectory = read_tum(child.out / "trajectory.tum")
    assert len(trajectory) == summary["scans"] <= total_scans
    if code == interrupted_code:
        assert summary["interrupted"] is True and marker["status"] == "interrupted"
        assert f"interrupted by {signal.Signals(child.signum).name}" in child.err
    else:
        assert "interrupted" not in summary and summary["scans"] == total_scans
        assert marker["status"] == "complete"
    return summary


def test_signals_at_start_up_while_processing_and_while_drawing(tmp_path):
    # long enough that the scans (read ahead by a child process, a fraction of a millisecond
    # each) are still being processed when the signal comes on a loaded machine
    long_log = write_carmen(tmp_path / "long.log", scans=3000)
    short_log = write_carmen(tmp_path / "short.log", scans=120)
    start = Child(short_log, tmp_path / "start", "--no-progress")
    middle = Child(long_log, tmp_path / "middle")  # the progress bar tells when it processes
    drawing = Child(short_log, tmp_path / "drawing", "--no-progress")
    wait_for(lambda: (start.marker() or {}).get("status") == "running")
    start.send(signal.SIGINT)
    wait_for(middle.processing)
    middle.send(signal.SIGTERM)
    wait_for(lambda: "map.pgm" in (drawing.marker() or {}).get("files", []))
    drawing.send(signal.SIGINT)

    summary = check_outcome(start, 120)
    assert start.proc.returncode == 130 and summary is not None
    summary = check_outcome(middle, 3000)
    assert middle.proc.returncode == 143 and 5 <= summary["scans"] < 3000
    summary = check_outcome(drawing, 120)
    assert drawing.proc.returncode == 130 and summary["scans"] == 120
    assert (tmp_path / "drawing" / "map.pgm").is_file()


def test_signals_at_random_moments(tmp_path):
    log = write_carmen(tmp_path / "room.log", scans=200)
    rng = random.Random(14)
    children = []
    for k in range(4):
        child = Child(log, tmp_path / f"o{k}", "--no-progress")
        children.append((child, rng.uniform(0.0, 4.0), rng.choice([signal.SIGINT,
                                                                   signal.SIGTERM])))
    for child, _, _ in children:
        wait_for(lambda c=child: c.handlers_installed() or c.proc.poll() is not None)
    started = time.monotonic()
    for child, delay, signum in sorted(children, key=lambda c: c[1]):
        time.sleep(max(0.0, started + delay - time.monotonic()))
        child.send(signum)
    for child, _, _ in children:
        check_outcome(child, 200)


def test_info_and_demo_stop_cleanly_and_say_so(tmp_path):
    log = write_carmen(tmp_path / "big.log", scans=3000)
    info = Child(None, tmp_path / "unused", "info", str(log))
    demo = Child(None, tmp_path / "demo", "demo", "--duration", "40", "--out",
                 str(tmp_path / "demo"), "--no-progress")
    wait_for(lambda: info.handlers_installed() or info.proc.poll() is not None)
    cpu = info.cpu_seconds()
    wait_for(lambda: info.cpu_seconds() > cpu + 0.5 or info.proc.poll() is not None)
    info.send(signal.SIGINT)
    wait_for(lambda: "world.png" in (demo.marker() or {}).get("files", []))
    cpu = demo.cpu_seconds()
    wait_for(lambda: demo.cpu_seconds() > cpu + 1.0 or demo.proc.poll() is not None)
    demo.send(signal.SIGTERM)

    code, stdout = info.finish()
    assert "Traceback" not in info.err and code in (0, 130), info.err
    if code == 130 and stdout:  # stopped while reading: what was read is reported
        summary = strict_json(stdout.strip().splitlines()[-1])
        assert summary["interrupted"] is True and summary["scans"] <= 3000
        assert "interrupted by SIGINT" in info.err
    summary = check_outcome(demo, 1600)
    assert demo.proc.returncode == 143 and (tmp_path / "demo" / "gt.tum").is_file()


@pytest.mark.parametrize("command", ["run", "demo"])
def test_a_signal_just_after_the_output_directory_is_made_still_writes_the_summary(
    tmp_path, monkeypatch, capsys, command
):
    """The output directory's marker says "running" from the moment it is made; a signal
    arriving just then (the start-up test's SIGINT, sent as soon as the marker appears,
    once in a few hundred runs) was raised before the section that writes the results, and
    the run exited 130 with the marker and no summary. It is now recorded and the results
    are written, marked interrupted."""
    import importlib

    from bioslam.cli import main

    module = importlib.import_module(f"bioslam.cli.{command}")
    made = module.open_output

    def open_then_signal(*args, **kwargs):
        out = made(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)  # handled as soon as control is back in Python
        return out

    monkeypatch.setattr(module, "open_output", open_then_signal)
    out = tmp_path / "out"
    if command == "run":
        argv = ["run", str(write_carmen(tmp_path / "short.log", scans=120)), "--out", str(out)]
    else:
        argv = ["demo", "--out", str(out), "--duration", "5"]
    code = main([*argv, "--no-progress"])
    assert code == 130
    summary = strict_json((out / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert strict_json(capsys.readouterr().out.strip().splitlines()[-1]) == summary
    assert json.loads((out / MARKER).read_text())["status"] == "interrupted"
