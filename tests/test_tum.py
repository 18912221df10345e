import numpy as np
import pytest

from bioslam.io.tum import read_tum, write_tum
from bioslam.trajectory import Trajectory


def test_tum_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    traj = Trajectory(np.arange(5) * 0.1 + 100.0, rng.uniform(-3, 3, (5, 3)))
    write_tum(tmp_path / "t.tum", traj)
    back = read_tum(tmp_path / "t.tum")
    assert np.allclose(back.stamps, traj.stamps)
    assert np.allclose(back.poses, traj.poses, atol=1e-6)
    assert back.path_length() == pytest.approx(traj.path_length(), abs=1e-5)


def test_tum_malformed_line_names_file_and_line(tmp_path):
    f = tmp_path / "bad.tum"
    f.write_text("# header\n0 0 0 0 0 0 0 1\n1 2 3\n")
    with pytest.raises(ValueError, match=r"bad.tum:3"):
        read_tum(f)
