"""Planar LiDAR models: beam layout, sweep timing and the measurement noise of real scanners.

Returns follow ROS REP 117, as real drivers report them: a beam with no return within
``range_max`` is ``+inf``, a target closer than ``range_min`` is ``-inf``, and a dropout (a
return the sensor failed to measure: dark or specular surfaces, grazing angles) is ``NaN``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

_FULL_TURN = 2.0 * np.pi


@dataclass(frozen=True)
class LidarModel:
    """A 2D scanning LiDAR.

    Attributes:
        name: preset name.
        fov: angular field of view, radians, centred on the forward axis; ``2*pi`` for a
            360-degree scanner (then beams are ``2*pi / beams`` apart and the last beam does not
            repeat the first).
        beams: beams per scan.
        range_min, range_max: valid range interval, metres.
        rate_hz: scans per second.
        noise_sigma: standard deviation of the Gaussian range noise, metres.
        dropout_prob: probability that a beam returns nothing (reported as NaN).
        sweep: model the rotating mirror: beam ``k`` is measured at ``stamp + k *
            time_increment`` from the pose the robot has then (a real scanner does this).
        mirror_hz: mirror revolutions per second when they differ from the scan rate (a SICK
            LMS 200 mirror turns at 75 Hz while a serial link delivers 5-10 scans a second);
            ``None`` = one revolution per scan.
        mount_yaw: the scanner's heading on the robot, radians counter-clockwise from its
            forward axis (pi: mounted facing backwards, as on a robot whose scanner's frame
            is turned round): the robot then drives backwards, or sideways, in the scan's
            own frame, which is the frame a LiDAR-only SLAM estimates.
        no_return_as_max: report a beam that met nothing as ``range_max`` instead of +inf, as
            loggers and drivers that do not follow REP 117 do.
        clockwise: the mirror turns clockwise: the beams come from the last angle to the first,
            so the scan's angles count down (a negative ROS ``angle_increment``, as a scanner
            mounted upside down or a 360° driver publishing clockwise reports).
    """

    name: str
    fov: float
    beams: int
    range_min: float
    range_max: float
    rate_hz: float
    noise_sigma: float = 0.0
    dropout_prob: float = 0.0
    sweep: bool = True
    mirror_hz: float | None = None
    mount_yaw: float = 0.0
    clockwise: bool = False
    no_return_as_max: bool = False

    def __post_init__(self) -> None:
        if self.beams < 2:
            raise ValueError(f"a LiDAR needs at least 2 beams, got {self.beams}")
        if not 0.0 < self.fov <= _FULL_TURN + 1e-9:
            raise ValueError(f"LiDAR field of view must be in (0, 2*pi], got {self.fov}")
        if not 0.0 <= self.range_min < self.range_max:
            raise ValueError(
                f"need 0 <= range_min < range_max, got {self.range_min}, {self.range_max}"
            )
        if not self.rate_hz > 0.0:
            raise ValueError(f"scan rate must be positive, got {self.rate_hz}")
        if self.noise_sigma < 0.0:
            raise ValueError(f"noise sigma must be >= 0, got {self.noise_sigma}")
        if not 0.0 <= self.dropout_prob <= 1.0:
            raise ValueError(f"dropout probability must be in [0, 1], got {self.dropout_prob}")
        if self.mirror_hz is not None and not self.mirror_hz >= self.rate_hz:
            raise ValueError(
                f"the mirror ({self.mirror_hz} Hz) cannot turn slower than scans arrive "
                f"({self.rate_hz} Hz)"
            )

    @property
    def full_circle(self) -> bool:
        return self.fov >= _FULL_TURN - 1e-9

    @property
    def angle_increment(self) -> float:
        return self.fov / (self.beams if self.full_circle else self.beams - 1)

    @property
    def angle_min(self) -> float:
        return -np.pi if self.full_circle else -0.5 * self.fov

    def angles(self) -> NDArray[np.float64]:
        """Beam angles in the sensor frame, radians, counter-clockwise from forward, in the
        order the mirror sweeps them."""
        angles = self.angle_min + self.angle_increment * np.arange(self.beams, dtype=np.float64)
        return angles[::-1].copy() if self.clockwise else angles

    @property
    def scan_time(self) -> float:
        """Seconds between scans (one mirror revolution)."""
        return 1.0 / self.rate_hz

    @property
    def time_increment(self) -> float:
        """Seconds between beams: the mirror turns a full circle per revolution at a constant
        rate, so a beam takes ``angle_increment / (2*pi)`` of a revolution (a revolution per
        scan unless ``mirror_hz`` says otherwise); 0 when the sweep is off."""
        if not self.sweep:
            return 0.0
        revolution = self.scan_time if self.mirror_hz is None else 1.0 / self.mirror_hz
        return revolution * self.angle_increment / _FULL_TURN

    def measure(self, true_ranges: NDArray[np.float64], rng: np.random.Generator) -> NDArray:
        """Turn exact distances (``inf`` = no hit) into what the sensor reports (float32):
        Gaussian noise, then the range limits, then dropouts (REP 117 codes, see module)."""
        r = np.asarray(true_ranges, dtype=np.float64)
        if self.noise_sigma > 0.0:
            r = r + rng.normal(0.0, self.noise_sigma, size=r.shape)
        out = r.astype(np.float32)
        out[r > self.range_max] = self.range_max if self.no_return_as_max else np.inf
        out[r < self.range_min] = -np.inf
        if self.dropout_prob > 0.0:
            out[rng.random(size=r.shape) < self.dropout_prob] = np.nan
        return out


LIDAR_PRESETS: dict[str, LidarModel] = {
    # Hokuyo UTM-30LX (the paper's robot, Sec. IV-B): datasheet 270 deg, 0.25 deg steps
    # (1081 beams), 0.1-30 m, 25 ms per scan; sigma 1 cm is the figure (datasheet:
    # +-3 cm accuracy up to 10 m).
    "utm30lx": LidarModel("utm30lx", np.deg2rad(270.0), 1081, 0.1, 30.0, 40.0, 0.01),
    # Hokuyo URG-04LX (BreezySLAM's exp1.dat): datasheet 240 deg, 682 beams, 0.02-5.6 m,
    # 100 ms per scan, accuracy +-1 cm below 1 m and 1 % beyond, taken as sigma 1 cm.
    "urg04lx": LidarModel("urg04lx", np.deg2rad(240.0), 682, 0.02, 5.6, 10.0, 0.01),
    # Slamtec RPLIDAR A1-class low-cost spinning LiDAR: 360 deg, 1 deg steps as the ROS
    # driver's default output, 0.15-12 m, ~7 Hz rotation; sigma 3 cm (datasheet: 1 % of range
    # plus quantisation, coarser than the Hokuyos).
    "rplidar": LidarModel("rplidar", 2.0 * np.pi, 360, 0.15, 12.0, 7.0, 0.03),
    # SICK LMS 200/291, the scanner of most public 2D datasets (Intel, the Freiburg and MIT
    # CARMEN logs): 180 deg at 1 deg (181 beams), 80 m range mode (datasheet: 1 cm resolution,
    # typical error +-4 cm there; sigma 1 cm as the utm30lx), scans at 10 Hz over a serial
    # link while the mirror turns at 75 Hz (so a 180 deg sweep takes 6.7 ms).
    "sick": LidarModel("sick", np.pi, 181, 0.1, 80.0, 10.0, 0.01, mirror_hz=75.0),
    # The same scanner's 0.5 deg mode (361 beams), which interlaces two mirror revolutions
    # (taken here as one at half speed); 5 Hz as freiburg-079-corrected (about 4 Hz).
    "sick361": LidarModel("sick361", np.pi, 361, 0.1, 80.0, 5.0, 0.01, mirror_hz=37.5),
    # ROBOTIS LDS-01, the TurtleBot3's: 360 deg at 1 deg (360 beams), 0.12-3.5 m, 300 rpm
    # (5 Hz); sigma 1.5 cm, the datasheet's +-15 mm below 0.5 m (its +-5 % beyond, a bound that
    # includes bias, is not modelled by range). The shortest reach of the presets: most of a
    # hall or an aisle is beyond it.
    "lds01": LidarModel("lds01", 2.0 * np.pi, 360, 0.12, 3.5, 5.0, 0.015),
}
