"""A robot that backs up: the constant-velocity prediction carries it on at its speed while it
drives back, two steps from the truth."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from _sim_runs import odometry_run

from bioslam.sim import LIDAR_PRESETS


def test_a_robot_backing_up_in_an_open_hall_is_followed_back():
    """The simulated pillar hall's ``reversing`` route (SICK, 361 beams at 5 Hz), 110 s from
    the origin, seed 31: the robot backs up from 0.5 m/s, the prediction lands 0.2 m on,
    and Gauss-Newton's basin there is narrower than that. Matched from the prediction alone
    the pose kept driving on (7.4 m off at the end); the match from the last step undone
    puts fewer endpoints where the map saw through, and wins."""
    estimate, truth = odometry_run("hall", "reversing", "sick361", 31, 110.0, start="origin")
    error = np.hypot(*(estimate[:, :2] - truth[:, :2]).T)
    assert error.max() < 0.15, error.max()


def test_a_robot_backing_up_along_a_corridor_its_walls_pin_across_only_is_followed_back(
    tmp_path: Path,
) -> None:
    """The twin-room floor (``benchmarks/twin_floor_plan.py``), its ``reversing`` route, seed
    472, SICK at 10 Hz sweeping clockwise, every 4th scan kept, from the origin: at 102 s the
    robot backs up at 0.5 m/s along the corridor. The walls pin the pose across it alone; the
    prediction 0.2 m on fits them as well as the truth 0.2 m back, and no endpoint lands
    where the map saw through; only the doors and corners fit less with every scan (score
    0.85 -> 0.77 -> 0.70 -> 0.65 -> 0.61). Matched from the prediction alone, six steps went on
    forward and the pose was 4.9 m off at 120 s. A score that drops below
    ``search_score_drop`` of the recent median is matched again from the last step undone,
    and the reversal is found at the second scan back."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from twin_floor_plan import write_twin

    estimate, truth = odometry_run(
        str(write_twin(tmp_path)), "reversing", replace(LIDAR_PRESETS["sick"], clockwise=True),
        472, 600.0, start="origin", every=4, until=120.0,
    )  # fmt: skip
    error = np.hypot(*(estimate[:, :2] - truth[:, :2]).T)
    # one step on past the reversal (0.4 m), none after it
    assert len(error) > 290 and error.max() < 0.5 and error[-1] < 0.1, (error.max(), error[-1])
