"""``bioslam eval``: table then JSON summary, clean errors on bad files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bioslam.cli import main
from bioslam.evaluation import evaluate
from bioslam.io.tum import read_tum, write_tum
from bioslam.trajectory import Trajectory

KEYS = [
    "ate_rmse_m",
    "ate_mean_m",
    "ate_max_m",
    "rpe_1m_trans_m",
    "rpe_1m_rot_deg",
    "rpe_1s_trans_m",
    "rpe_1s_rot_deg",
    "pairs",
]


def _circle(n: int = 200, radius: float = 3.0, t0: float = 50.0) -> Trajectory:
    phi = np.linspace(0.0, 2.0 * np.pi, n)
    poses = np.column_stack([radius * np.cos(phi), radius * np.sin(phi), phi + np.pi / 2])
    return Trajectory(t0 + 0.1 * np.arange(n), poses)


def _write(tmp_path, name: str, trajectory: Trajectory):
    path = tmp_path / name
    write_tum(path, trajectory)
    return path


def test_eval_prints_a_table_and_the_json_summary(tmp_path, capsys):
    gt = _circle()
    est = Trajectory(gt.stamps + 0.005, gt.poses + np.array([0.1, 0.0, 0.0]))
    est_path, gt_path = _write(tmp_path, "est.tum", est), _write(tmp_path, "gt.tum", gt)
    assert main(["eval", str(est_path), str(gt_path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    summary = json.loads(out[-1])
    assert list(summary) == KEYS
    assert any("ATE rmse" in line for line in out[:-1])
    expected = evaluate(read_tum(est_path), read_tum(gt_path))
    for key in KEYS:
        assert summary[key] == pytest.approx(expected[key], rel=1e-12, abs=1e-12)
    # A constant offset is removed by the alignment; the heading is unchanged, so RPE is ~0.
    assert summary["ate_rmse_m"] < 1e-5
    assert summary["pairs"] == len(gt)


def test_eval_max_dt_controls_the_association(tmp_path, capsys):
    gt = _circle()
    est = Trajectory(gt.stamps + 0.03, gt.poses)
    est_path, gt_path = _write(tmp_path, "est.tum", est), _write(tmp_path, "gt.tum", gt)
    assert main(["eval", str(est_path), str(gt_path)]) == 2
    assert "no matching stamps" in capsys.readouterr().err
    assert main(["eval", str(est_path), str(gt_path), "--max-dt", "0.04"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["pairs"] == len(gt)


def test_eval_reports_a_short_path_rpe_as_null(tmp_path, capsys):
    n = 12  # enough poses for an ATE, a path far shorter than the 1 m of an RPE pair
    gt = Trajectory(np.arange(n) * 0.1, np.column_stack([np.arange(n) * 0.01, np.zeros((n, 2))]))
    path = _write(tmp_path, "gt.tum", gt)
    assert main(["eval", str(path), str(path)]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert summary["rpe_1m_trans_m"] is None
    assert summary["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)


def test_eval_names_the_bad_file(tmp_path, capsys):
    gt_path = _write(tmp_path, "gt.tum", _circle())
    empty = tmp_path / "empty.tum"
    empty.write_text("# nothing here\n")
    assert main(["eval", str(empty), str(gt_path)]) == 2
    err = capsys.readouterr().err
    assert "empty.tum" in err and "no poses" in err

    late_path = _write(tmp_path, "late.tum", _circle(t0=5000.0))
    assert main(["eval", str(late_path), str(gt_path)]) == 2
    err = capsys.readouterr().err
    assert "late.tum" in err and "gt.tum" in err

    assert main(["eval", str(tmp_path / "missing.tum"), str(gt_path)]) == 2
    assert "missing.tum" in capsys.readouterr().err


def test_eval_with_a_third_trajectory_splits_the_error_between_estimate_and_reference(
    tmp_path, capsys
):
    truth = _circle(n=2000, radius=8.0)
    rng = np.random.default_rng(4)

    def noisy(sigma: float) -> Trajectory:
        return Trajectory(
            truth.stamps, truth.poses + rng.normal(0.0, [sigma, sigma, 0.0], (2000, 3))
        )

    # a noisy reference, a good estimate and a middling third
    paths = [
        _write(tmp_path, f"{name}.tum", noisy(s))
        for name, s in (("gt", 0.03), ("est", 0.005), ("third", 0.015))
    ]
    gt_path, est_path, third_path = paths
    assert main(["eval", str(est_path), str(gt_path), "--third", str(third_path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    hat = json.loads(out[-1])["three_cornered_hat"]
    assert hat["order"] == ["reference", "estimate", "third"]
    reference, estimate, third = hat["trans_rmse_m"]
    # independent per-pose noise s gives a pair error of s * sqrt(2) per axis, i.e. 2 s in 2-D
    assert reference == pytest.approx(2 * 0.03, rel=0.15)
    assert estimate < third < reference
    assert any(line.strip().startswith("reference") for line in out[:-1])

    assert main(["eval", str(est_path), str(gt_path), "--third", str(tmp_path / "no.tum")]) == 2
    assert "no.tum" in capsys.readouterr().err
