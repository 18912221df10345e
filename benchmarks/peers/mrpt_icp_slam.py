"""MRPT's ``icp-slam`` as a LiDAR-only peer: setup, conversion, running, reading poses back.

Pipeline: scans (any format bioslam reads) -> a CARMEN log written here -> ``carmen2rawlog`` ->
``icp-slam`` with an .ini adapted from the one MRPT ships -> ``log_estimated_path.txt`` ->
one pose per input scan, mapped back to the scans' stamps by index.

Traps of MRPT's CARMEN converter (MRPT 2.5, ``libs/obs/src/carmen_log_tools.cpp``) and how they
are avoided:

* ``FLASER``'s second pose triple becomes odometry; in corrected logs it is the reference, so
  feeding the original log would leak the answer. We write our own log with every pose field
  constant (zero), so the peer is LiDAR only like bioslam.
* ``FLASER`` assumes 0.5 deg per beam unless a ``PARAM laser_front_laser_resolution`` says
  otherwise, and MRPT centres every scan on the sensor axis. We write ``ROBOTLASER1`` lines
  instead: they carry the field of view explicitly (aperture = (n-1) * increment, MRPT's
  convention) and the laser-vs-robot pose triple carries the yaw of the scan centre, so
  asymmetric scans (180 beams over [-90, 89] deg) are placed right.
* The converted rawlog gives every observation the same time stamp (checked with
  ``rawlog-edit --export-2d-scans-txt`` on MRPT 2.5.8), and ``icp-slam`` writes its path by step
  number, not by time. We map the path back to the scans' stamps by index: each ROBOTLASER1 line
  yields two observations (odometry, laser), so the pose after laser ``k`` is step ``2k + 1``.
* With constant odometry, ``CMetricMapBuilderICP`` skips ICP while the odometric displacement
  since the last correction is below ``localizationLinDistance``/``AngDistance``; both are set
  to 0 so that every scan is registered.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bioslam.scan import LaserScan
from bioslam.trajectory import Trajectory

APT_PACKAGES = ("mrpt-apps", "mrpt-common")
SHIPPED_INI = Path("/usr/share/mrpt/config_files/icp-slam/icp-slam_demo_classic.ini")
MRPT_STEPS_PER_SCAN = 2  # carmen2rawlog emits an odometry and a laser observation per line

# How the benchmark runs the app: headless, no per-step 3D scenes (they would dominate the time),
# and ICP at every scan: with constant odometry MRPT would otherwise skip ICP until the
# (never growing) odometric displacement exceeds these distances.
RUN_MAPPING = {
    "LOG_FREQUENCY": "1000000",
    "SAVE_3D_SCENE": "0",
    "SAVE_POSE_LOG": "0",
    "SHOW_PROGRESS_3D_REAL_TIME": "0",
    "localizationLinDistance": "0",
    "localizationAngDistance": "0",
}
# [ICP] as shipped except as noted. Without odometry the only motion prior is the last pose, so
# the correspondence gate has to cover one scan's motion: 0.3 m (shipped) -> 1.0 m, and the
# angular gate 5 -> 15 deg (a robot turning at 60 deg/s with a 4 Hz sensor). Levenberg-Marquardt
# instead of classic ICP: the shipped alternative (icp-slam_demo_LM.ini). Chosen among six
# variants (shipped, wider gates, decimation 2, LM, LM with shipped gates, LM with 0.5 m gates)
# on the first 1000 scans of freiburg-079: ATE 8.0 m shipped, 3.5 m wider gates, 0.12 m both.
DEFAULT_ICP: dict[str, str] = {
    "thresholdDist": "1.0",
    "thresholdAng_DEG": "15",
    "ICP_algorithm": "icpLevenbergMarquardt",
}
# [MappingApplication] as shipped (insertion every 1.2 m / 45 deg, ICP goodness >= 0.40).
DEFAULT_MAPPING: dict[str, str] = {}


@dataclass
class IcpSlamConfig:
    """Settings changed from MRPT's shipped ``icp-slam_demo_classic.ini`` (others kept as shipped).

    ``icp``: overrides of the ``[ICP]`` section. ``mapping``: overrides of
    ``[MappingApplication]``. ``max_range_m``: used when a scan says its range is unlimited
    (CARMEN's 81 m default). See ``DEFAULT_ICP`` / ``DEFAULT_MAPPING`` for why each is changed.
    """

    icp: dict[str, str] = field(default_factory=lambda: dict(DEFAULT_ICP))
    mapping: dict[str, str] = field(default_factory=lambda: dict(DEFAULT_MAPPING))
    max_range_m: float = 81.0


class PeerUnavailableError(RuntimeError):
    """The peer could not be installed or run on this machine."""


def ensure_installed(allow_install: bool = True) -> None:
    """Install MRPT's apps with apt when missing (a benchmark setup step, not a package dep)."""
    if shutil.which("icp-slam") and shutil.which("carmen2rawlog") and SHIPPED_INI.exists():
        return
    if not allow_install:
        raise PeerUnavailableError("icp-slam/carmen2rawlog missing (apt-get install mrpt-apps)")
    sudo = [] if os.geteuid() == 0 else ["sudo", "-n"]
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (
        [*sudo, "apt-get", "update"],
        [*sudo, "apt-get", "install", "-y", "--no-install-recommends", *APT_PACKAGES],
    ):
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise PeerUnavailableError(f"{' '.join(cmd)} failed: {proc.stderr.strip()[-300:]}")
    if not shutil.which("icp-slam"):
        raise PeerUnavailableError("mrpt-apps installed but icp-slam is not on PATH")


def robotlaser_line(scan: LaserScan, t_rel: float, max_range: float) -> str:
    """One CARMEN ``ROBOTLASER1`` line for ``scan`` with all pose fields LiDAR-only (zero)."""
    n = scan.num_beams
    increment = (scan.angles[-1] - scan.angles[0]) / (n - 1) if n > 1 else 0.0
    aperture = abs(increment) * (n - 1)
    centre = 0.5 * (scan.angles[0] + scan.angles[-1])
    # MRPT sweeps right to left (increasing angle); a clockwise sensor is reversed here.
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    if increment < 0:
        ranges = ranges[::-1]
    rmax = scan.range_max if math.isfinite(scan.range_max) else max_range
    valid = scan.valid_mask if increment >= 0 else scan.valid_mask[::-1]
    # 0 marks "no return" for MRPT's parser (it treats r <= 0 and r >= max as invalid).
    out = np.where(valid & (ranges < rmax), ranges, 0.0)
    fields = [
        "ROBOTLASER1", "0", f"{-0.5 * aperture:.9f}", f"{aperture:.9f}", f"{abs(increment):.9f}",
        f"{rmax:.3f}", "0.01", "0", str(n), " ".join(f"{r:.4f}" for r in out), "0",
        # laser pose minus robot pose = sensor mounting: only the yaw of the scan centre.
        "0 0", f"{centre:.9f}", "0 0 0",
        "0 0 0 0 0",  # tv rv forward_safety side_safety turn_axis
        f"{t_rel:.6f}", "bench", f"{t_rel:.6f}",
    ]  # fmt: skip
    return " ".join(fields)


def write_carmen(scans: Iterable[LaserScan], path: Path, cfg: IcpSlamConfig) -> list[float]:
    """Write ``scans`` as a LiDAR-only CARMEN log; returns the stamps in file order."""
    stamps: list[float] = []
    with Path(path).open("w") as fh:
        fh.write("# written by bioslam benchmarks: LiDAR only, odometry fields constant\n")
        for scan in scans:
            if scan.num_beams < 2:
                continue
            t0 = stamps[0] if stamps else scan.stamp
            fh.write(robotlaser_line(scan, scan.stamp - t0, cfg.max_range_m) + "\n")
            stamps.append(float(scan.stamp))
    if not stamps:
        raise ValueError(f"{path}: no scans with at least two beams to convert")
    return stamps


def write_ini(out_dir: Path, rawlog: Path, cfg: IcpSlamConfig) -> Path:
    """Adapt MRPT's shipped classic ICP config: no GUI, no 3D scenes, ICP at every scan."""
    overrides = {
        "rawlog_file": str(rawlog),
        "logOutput_dir": str(out_dir / "log"),
        **RUN_MAPPING,
        **cfg.mapping,
        **cfg.icp,
    }
    lines = []
    for line in SHIPPED_INI.read_text().splitlines():
        key = line.split("=", 1)[0].strip()
        if "=" in line and key in overrides:
            line = f"{key} = {overrides.pop(key)}"
        lines.append(line)
    if overrides:
        raise PeerUnavailableError(f"{SHIPPED_INI}: keys not found to adapt: {sorted(overrides)}")
    ini = out_dir / "icp-slam.ini"
    ini.write_text("\n".join(lines) + "\n")
    return ini


def convert(
    scans: Iterable[LaserScan], work: Path, cfg: IcpSlamConfig
) -> tuple[Path, Path, list[float]]:
    """Scans -> CARMEN -> rawlog; returns ``(ini, rawlog, stamps)`` (untimed preprocessing)."""
    work.mkdir(parents=True, exist_ok=True)
    carmen = work / "lidar_only.carmen.log"
    rawlog = work / "lidar_only.rawlog"
    stamps = write_carmen(scans, carmen, cfg)
    proc = subprocess.run(
        ["carmen2rawlog", "-q", "-w", "-i", str(carmen), "-o", str(rawlog)],
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0 or not rawlog.exists():
        detail = proc.stderr.strip()[-300:]
        raise PeerUnavailableError(f"carmen2rawlog failed on {carmen}: {detail}")
    return write_ini(work, rawlog, cfg), rawlog, stamps


def command(ini: Path) -> list[str]:
    """The timed command line (the rawlog path is in the ini)."""
    return ["icp-slam", str(ini)]


def read_path(work: Path, stamps: Sequence[float]) -> Trajectory:
    """Map ``log_estimated_path.txt`` (``step x y phi`` per observation) back to scan stamps."""
    path_file = work / "log" / "log_estimated_path.txt"
    if not path_file.exists():
        raise PeerUnavailableError(f"{path_file}: icp-slam wrote no path")
    table = np.loadtxt(path_file, ndmin=2)
    steps = table[:, 0].astype(int)
    want = np.arange(len(stamps)) * MRPT_STEPS_PER_SCAN + MRPT_STEPS_PER_SCAN - 1
    found = np.searchsorted(steps, want)
    ok = (found < len(steps)) & (steps[np.minimum(found, len(steps) - 1)] == want)
    if not ok.all():
        raise PeerUnavailableError(
            f"{path_file}: {int((~ok).sum())} of {len(stamps)} scans have no pose "
            f"(last step {steps[-1]})"
        )
    rows = table[found, 1:4]
    return Trajectory(np.asarray(stamps), rows)


def per_scan_ms(work: Path, n_scans: int) -> np.ndarray:
    """Per-laser-scan processing time from ``log_times.txt`` (odometry steps left out)."""
    times = np.loadtxt(work / "log" / "log_times.txt", ndmin=2)[:, 0]
    return times[MRPT_STEPS_PER_SCAN - 1 :: MRPT_STEPS_PER_SCAN][:n_scans]


def map_pictures(work: Path) -> list[Path]:
    """Map images icp-slam left in its log folder (grid maps as .png, if configured)."""
    return sorted((work / "log").glob("*.png"))


def render_point_map(work: Path, resolution_m: float = 0.05) -> Path | None:
    """Rasterise icp-slam's final point map (``x y z`` text) into a PNG beside it."""
    from PIL import Image

    hits = sorted((work / "log").glob("_finalmaps_.txt_*PointsMap*.txt"))
    if not hits:
        return None
    pts = np.loadtxt(hits[0], ndmin=2)[:, :2]
    if pts.size == 0:
        return None
    ij = np.floor((pts - pts.min(axis=0)) / resolution_m).astype(int)
    w, h = ij.max(axis=0) + 1
    img = np.full((h, w), 255, dtype=np.uint8)
    img[h - 1 - ij[:, 1], ij[:, 0]] = 0  # image rows grow downwards, map y upwards
    out = work / "map.png"
    Image.fromarray(img).save(out)
    return out
