"""The output directory of a run: checked before the run, owned through a marker file.

A run's directory must hold only that run's files, and a run must never destroy a user's other
files. So a run writes a marker, :data:`MARKER`, listing the command, the version, the start
time and every file it wrote (updated after each file, so that even a killed run leaves an
accurate list). An existing non-empty directory is refused unless the caller asks to overwrite
it; overwriting removes exactly the files a previous run's marker lists, nothing else.

Each output is written through :meth:`OutputDir.write`: a failure to write one file (a full
disk, a permission) is recorded with the file's name and the other outputs are still written.
"""

from __future__ import annotations

import datetime
import json
import shutil
import stat
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path, PurePosixPath
from typing import Any

from bioslam.io.jsonio import write_json

MARKER = ".bioslam-run.json"
#: Room kept for the outputs whose size does not grow with the log: the rendered map (at most
#: 4000 x 4000 cells, 16 MB), the figures (~1 MB each) and the summaries.
FIXED_OUTPUT_BYTES = 32 * 2**20


def expected_output_bytes(scans: int | None = None, input_bytes: int | None = None) -> int:
    """An upper estimate of what a run writes: two TUM lines (~100 bytes each) and a
    cognitive-map node (~300 bytes) per scan; without a scan count, a quarter of the log's
    size (a scan record takes at least 1 kB in every supported format)."""
    per_log = 500 * scans if scans is not None else (input_bytes or 0) // 4
    return FIXED_OUTPUT_BYTES + per_log


def path_bytes(path: Path) -> int:
    """Size of a file, or the summed size of the files in a directory (a ROS 2 bag)."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def _existing_ancestor(path: Path) -> Path:
    path = path.absolute()
    while not path.exists():
        path = path.parent
    return path


def check_output_dir(path: Path, overwrite: bool, needed_bytes: int) -> None:
    """Refuse, before any work, an output path that cannot take the run's results.

    Raises ``ValueError`` (a file, a directory of other files, not enough space) or
    ``PermissionError`` (not writable) naming the path.
    """
    if path.exists() and not path.is_dir():
        raise ValueError(f"--out {path} is a file, not a directory")
    if path.is_dir() and any(path.iterdir()) and not overwrite:
        what = "a previous run's results" if (path / MARKER).exists() else "other files"
        raise ValueError(
            f"--out {path} already holds {what}; pass --overwrite to replace a previous "
            "run's files (other files are left alone) or choose a new directory"
        )
    base = _existing_ancestor(path)
    if not base.is_dir():
        raise ValueError(f"--out {path}: {base} is a file, not a directory")
    try:
        with tempfile.TemporaryFile(dir=base):
            pass
    except OSError as exc:
        raise PermissionError(f"--out {path}: cannot write in {base}: {exc.strerror}") from None
    free = shutil.disk_usage(base).free
    if free < needed_bytes:
        raise ValueError(
            f"--out {path}: {free / 2**20:.0f} MB free on its disk, the run's outputs need "
            f"about {needed_bytes / 2**20:.0f} MB"
        )
    if overwrite and (path / MARKER).exists():
        _listed_files(path)  # a marker that cannot be read is refused now, not after the run


def _listed_files(directory: Path) -> list[str]:
    marker = directory / MARKER
    try:
        files = json.loads(marker.read_text(encoding="utf-8"))["files"]
        if not all(isinstance(name, str) for name in files):
            raise TypeError("file names must be strings")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(
            f"{marker}: unreadable marker of a previous run ({exc}); not overwriting "
            f"{directory}: remove it by hand or choose another directory"
        ) from None
    return files


def _inside(directory: Path, name: str) -> Path | None:
    """``directory / name`` when ``name`` is a plain relative path that stays inside."""
    rel = PurePosixPath(name)
    if rel.is_absolute() or not rel.parts or ".." in rel.parts or rel.name == MARKER:
        return None
    return directory.joinpath(*rel.parts)


def remove_previous_run(directory: Path) -> list[str]:
    """Remove the regular files a previous run's marker lists (and sub-directories left
    empty by that); returns the names removed. Anything else in the directory stays."""
    if not (directory / MARKER).exists():
        return []
    removed = []
    for name in _listed_files(directory):
        target = _inside(directory, name)
        if target is None:
            continue
        try:
            if stat.S_ISREG(target.lstat().st_mode):
                target.unlink()
                removed.append(name)
        except FileNotFoundError:
            continue
        parent = target.parent
        while parent != directory:
            try:
                parent.rmdir()  # only succeeds when empty
            except OSError:
                break
            parent = parent.parent
    (directory / MARKER).unlink()
    return removed


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


class OutputDir:
    """A run's output directory: the marker, the files written and the failures.

    Attributes:
        path: the directory.
        written: files written, relative to ``path`` (POSIX separators).
        errors: ``"FILE: reason"`` for each output that could not be written.
    """

    def __init__(self, path: str | Path, command: Sequence[str] = (), marker: bool = True) -> None:
        self.path = Path(path)
        self.written: list[str] = []
        self.errors: list[str] = []
        self._marker = marker
        self._info: dict[str, Any] = {"command": list(command), "started": _now()}

    def prepare(self, overwrite: bool = False) -> list[str]:
        """Create the directory (removing a previous run's files with ``overwrite``) and write
        the marker; returns the names of the removed files."""
        removed = remove_previous_run(self.path) if overwrite and self.path.is_dir() else []
        self.path.mkdir(parents=True, exist_ok=True)
        self._save("running")
        return removed

    def write(self, names: str | Sequence[str], action: Callable[[], Any]) -> bool:
        """Run ``action`` (which writes ``names``, relative to the directory); an ``OSError``
        is recorded against the first name and ``False`` returned, not raised."""
        names = [names] if isinstance(names, str) else list(names)
        try:
            action()
        except OSError as exc:
            reason = exc.strerror or str(exc)
            self.errors.append(f"{self.path / names[0]}: {reason}")
            return False
        self.written += [n for n in names if n not in self.written]
        self._save("running")
        return True

    def save(self, name: str, writer: Callable[..., Any], *args: Any) -> bool:
        """``writer(path / name, *args)`` through :meth:`write`."""
        return self.write(name, lambda: writer(self.path / name, *args))

    def finish(self, status: str) -> None:
        """Record the run's end (``complete``, ``interrupted``, ``failed``) in the marker."""
        self._info["finished"] = _now()
        self._save(status)

    def _save(self, status: str) -> None:
        if not self._marker:
            return
        from bioslam import __version__

        data = {"bioslam": __version__, **self._info, "status": status, "files": self.written}
        try:
            write_json(self.path / MARKER, data)
        except OSError as exc:
            message = f"{self.path / MARKER}: {exc.strerror or exc}"
            if message not in self.errors:
                self.errors.append(message)

    def __repr__(self) -> str:
        return f"OutputDir({str(self.path)!r}, written={len(self.written)})"


__all__ = [
    "MARKER",
    "OutputDir",
    "check_output_dir",
    "expected_output_bytes",
    "path_bytes",
    "remove_previous_run",
]
