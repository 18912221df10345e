"""The benchmark cases: what each one feeds the SLAM systems and what it is judged against.

A case is prepared once per run into a work folder: the input file that ``bioslam run`` reads,
the scans in memory (for the peer's conversion and the loop check), and a reference TUM file
when one exists (the simulator's ground truth, or the corrected poses a CARMEN log carries).
Real logs are never copied into the repository; ``--quick`` reads only their first scans, by
writing a shortened copy into the (untracked) work folder.
"""

from __future__ import annotations

import gzip
import subprocess
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bioslam.io.tum import write_tum
from bioslam.scan import LaserScan
from bioslam.trajectory import Trajectory

REPO_ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = REPO_ROOT.parent / "shared" / "data"
CARMEN_SCAN_MESSAGES = ("FLASER", "RLASER", "ROBOTLASER", "RAWLASER")


@dataclass(frozen=True)
class Case:
    """One benchmark input.

    ``source``: ``"sim"`` (generated with ``bioslam sim``) or a file name in ``../shared/data``.
    ``lidar`` / ``duration_s`` / ``seed`` / ``world`` / ``route``: the simulator's settings
    (sim cases; ``bioslam sim --world``, ``--route``).
    ``thin_m``: thin the input to one scan per that many metres travelled (``bioslam thin``,
    along the ground truth or the log's reference), as the public "corrected" logs were made;
    0 = every scan.
    ``max_scans``: read only the first scans of a real log (quick runs); ``None`` = all.
    ``repeats``: the most timed repetitions worth spending on this case (long cases run once).
    ``settings``: JSON overrides of the bioslam configuration for both bioslam rows (e.g. an
    injected heading drift for the ablation); empty = defaults.
    """

    name: str
    source: str
    description: str
    lidar: str = ""
    duration_s: float = 0.0
    seed: int = 1
    max_scans: int | None = None
    repeats: int = 3
    settings: str = ""
    world: str = "maze"
    route: str = "tour"
    thin_m: float = 0.0


@dataclass
class PreparedCase:
    """A case ready to run: ``input_path`` for ``bioslam run``, scans, optional reference."""

    case: Case
    input_path: Path
    scans: list[LaserScan]
    reference_tum: Path | None
    notes: list[str] = field(default_factory=list)
    config_path: Path | None = None

    @property
    def stamps(self) -> np.ndarray:
        return np.array([s.stamp for s in self.scans])

    @property
    def duration_s(self) -> float:
        return float(self.scans[-1].stamp - self.scans[0].stamp) if self.scans else 0.0


def full_cases() -> list[Case]:
    """The issue's cases at full length, real logs first (they are short and most telling)."""
    return [
        Case("freiburg-079", "freiburg-079-corrected.log.gz",
             "CARMEN, Freiburg bldg 079, SICK 180°/0.5°; reference = corrected poses", repeats=2),
        Case("intel", "intel-corrected.log.gz",
             "CARMEN, Intel Seattle (thinned), SICK 180°/1°; reference = corrected poses"),
        Case("exp1", "exp1.dat", "BreezySLAM exp1, URG-04LX 240°; no reference"),
        Case("ros1-bag", "laser_scan_matcher_demo.bag", "ROS 1 bag, handheld Hokuyo; no reference"),
        Case("sim-long-rplidar", "sim", "simulated maze, 20 min route, 360° RPLIDAR A1",
             lidar="rplidar", duration_s=1200.0, seed=2, repeats=1),
        Case("sim-maze-utm30lx", "sim", "simulated maze of the demo, 600 s, Hokuyo UTM-30LX",
             lidar="utm30lx", duration_s=600.0, repeats=1),
        Case("sim-long-gyro-bias", "sim",
             "ablation: the 20 min RPLIDAR route with a gyro-like heading drift of 0.0115 deg/s "
             "added to the odometry", lidar="rplidar", duration_s=1200.0, seed=2, repeats=1,
             settings=GYRO_BIAS_SETTINGS),
        *repetitive_cases(),
    ]  # fmt: skip


def repetitive_cases() -> list[Case]:
    """Simulated cases the dense maze hides: identical aisles and rooms, sparse and short-range
    scanners, routes that weave off the centre-line and turn back."""
    return [
        Case("sim-warehouse-sick", "sim",
             "warehouse of identical aisles, 600 s, SICK LMS 180°/1° (181 beams), 10 Hz",
             lidar="sick", duration_s=600.0, repeats=1, world="warehouse"),
        Case("sim-warehouse-utm30lx", "sim",
             "warehouse of identical aisles, 600 s, Hokuyo UTM-30LX",
             lidar="utm30lx", duration_s=600.0, repeats=1, world="warehouse"),
        Case("sim-maze-urg04lx", "sim",
             "maze of the demo, 600 s, Hokuyo URG-04LX 240°, 5.6 m, 10 Hz",
             lidar="urg04lx", duration_s=600.0, repeats=1),
        Case("sim-rooms-sick-adversarial", "sim",
             "identical rooms off a corridor, 600 s, SICK 181 beams, adversarial route (0.5 m "
             "off centre, turn-backs, spins then 1.2 m/s)",
             lidar="sick", duration_s=600.0, repeats=1, world="rooms", route="adversarial"),
        Case("sim-warehouse-utm30lx-adversarial", "sim",
             "warehouse, 600 s, Hokuyo UTM-30LX, adversarial route",
             lidar="utm30lx", duration_s=600.0, repeats=1, world="warehouse",
             route="adversarial"),
        Case("freiburg-079-thin1m", "freiburg-079-corrected.log.gz",
             "freiburg-079 thinned to one scan per metre along its corrected poses (as public "
             "corrected logs were made); reference = corrected poses", thin_m=1.0),
        Case("sim-warehouse-sick-thin1m", "sim",
             "sim-warehouse-sick thinned to one scan per metre of ground truth",
             lidar="sick", duration_s=600.0, repeats=1, world="warehouse", thin_m=1.0),
        Case("sim-maze-sick-thin1m", "sim",
             "the demo's maze, 600 s, SICK 181 beams, thinned to one scan per metre",
             lidar="sick", duration_s=600.0, repeats=1, thin_m=1.0),
    ]  # fmt: skip


#: The ablation's injected drift: 0.0115 deg/s (41 deg/h), a consumer MEMS gyro's bias stability.
GYRO_BIAS_SETTINGS = '{"heading_bias": 0.0002}'


def quick_cases() -> list[Case]:
    """Short versions of the same cases (``--quick``, about 5 min), one timed run each."""
    short = {"sim-maze-utm30lx": 20.0}
    heads = {"freiburg-079": 300, "intel": 150, "exp1": 300}
    out = []
    for c in full_cases():
        if c.source == "sim":
            length = short.get(c.name, 120.0 if c.thin_m else 60.0)
            out.append(replace(c, duration_s=length, repeats=1))
        else:
            out.append(replace(c, max_scans=heads.get(c.name), repeats=1))
    return out


def bioslam_cli() -> list[str]:
    """The ``bioslam`` command of the interpreter running the benchmark."""
    return [sys.executable, "-m", "bioslam.cli"]


def _find_bag(folder: Path) -> Path:
    for pattern in ("**/metadata.yaml", "**/*.bag", "**/*.mcap", "**/*.db3"):
        hits = sorted(folder.glob(pattern))
        if hits:
            return hits[0].parent if hits[0].name == "metadata.yaml" else hits[0]
    raise FileNotFoundError(f"{folder}: bioslam sim wrote no bag")


def _simulate(case: Case, folder: Path) -> tuple[Path, Path]:
    gt = folder / "gt.tum"
    if not gt.exists():
        cmd = [
            *bioslam_cli(),
            "sim",
            "--world",
            case.world,
            "--route",
            case.route,
            "--lidar",
            case.lidar,
            "--duration",
            f"{case.duration_s:g}",
            "--seed",
            str(case.seed),
            "--out",
            str(folder),
        ]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd[2:])} failed: {proc.stderr.strip()[-400:]}")
    return _find_bag(folder), gt


def _thin(case: Case, source: Path, reference: Path | None, folder: Path) -> Path:
    """``bioslam thin`` of a case's input into ``folder``: by the simulator's ground truth (a
    bag and gt.tum), or by a CARMEN log's corrected poses (a CARMEN log)."""
    if reference is not None:
        out, by, result = folder, ["--by", str(reference)], folder / "scans"
    else:
        name = source.name.removesuffix(".gz")
        out = result = folder / f"thin{case.thin_m:g}m-{name}"
        by = []
    if not result.exists():
        cmd = [*bioslam_cli(), "thin", str(source), "--out", str(out), "--distance",
               f"{case.thin_m:g}", *by]  # fmt: skip
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd[2:])} failed: {proc.stderr.strip()[-400:]}")
    return result


def _is_scan_line(line: str, fmt: str) -> bool:
    if fmt == "breezyslam":
        return bool(line.strip())
    return line.startswith(CARMEN_SCAN_MESSAGES)


def shorten_text_log(src: Path, dst: Path, max_scans: int, fmt: str) -> Path:
    """Copy ``src`` up to its ``max_scans``-th scan line (header and parameters kept)."""
    opener = gzip.open if src.suffix == ".gz" else open
    count = 0
    with opener(src, "rt") as fin, dst.open("w") as fout:
        for line in fin:
            if _is_scan_line(line, fmt):
                if count >= max_scans:
                    break
                count += 1
            fout.write(line)
    return dst


def _real_log(case: Case, folder: Path) -> Path:
    from bioslam.io.logs import detect_format

    src = DATA_DIR / case.source
    if not src.exists():
        raise FileNotFoundError(f"{src}: real log not found (../shared/data is absent)")
    if case.max_scans is None:
        return src
    fmt = detect_format(src)
    if fmt not in ("carmen", "breezyslam"):
        return src  # binary logs are short enough to run whole
    name = src.name.removesuffix(".gz")
    return shorten_text_log(src, folder / f"head{case.max_scans}-{name}", case.max_scans, fmt)


def prepare(case: Case, work: Path) -> PreparedCase:
    """Generate or locate the input, load its scans and write the reference TUM if any."""
    from bioslam.io.logs import open_log

    # The simulator's settings are part of the folder name: a cached bag is reused only when
    # it was generated with the same lidar, duration and seed.
    # Cases driving the same simulated route share its folder.
    place = "" if (case.world, case.route) == ("maze", "tour") else f"{case.world}-{case.route}-"
    sim_key = f"sim-{place}{case.lidar}-{case.duration_s:g}s-seed{case.seed}"
    folder = work / "cases" / (sim_key if case.source == "sim" else case.name)
    folder.mkdir(parents=True, exist_ok=True)
    notes: list[str] = []
    if case.source == "sim":
        input_path, reference = _simulate(case, folder)
    else:
        input_path, reference = _real_log(case, folder), None
    if case.thin_m:
        if case.source == "sim":  # the simulated route's folder is shared: thin beside it
            folder = folder.parent / f"{folder.name}-thin{case.thin_m:g}m"
            folder.mkdir(parents=True, exist_ok=True)
        input_path = _thin(case, Path(input_path), reference, folder)
        reference = folder / "gt.tum" if reference is not None else None
    log = open_log(input_path)
    scans = list(log)
    if not scans:
        raise ValueError(f"{input_path}: no usable scans")
    skipped = log.skipped
    if skipped:
        notes.append(f"skipped records: {skipped}")
    if reference is None and log.reference is not None and len(log.reference):
        reference = folder / "reference.tum"
        write_tum(reference, log.reference)
    config_path = None
    if case.settings:
        config_path = folder / f"{case.name}-config.json"
        config_path.write_text(case.settings)
    return PreparedCase(case, Path(input_path), scans, reference, notes, config_path)


def read_reference(prepared: PreparedCase) -> Trajectory | None:
    from bioslam.io.tum import read_tum

    return read_tum(prepared.reference_tum) if prepared.reference_tum else None
