"""Where the shared real logs are (``../shared/data`` beside the repository), for the io tests."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def shared_log(name: str) -> Path:
    """Path of a shared log, or skip the test when the folder (or the file) is absent."""
    path = SHARED_DATA / name
    if not path.exists():
        pytest.skip(f"shared log {name} not found in {SHARED_DATA} (a fresh clone has none)")
    return path
