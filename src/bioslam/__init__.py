"""bioslam: biologically-inspired 2D LiDAR SLAM (Zhuang et al.).

LiDAR odometry (Sec. III-A), LiDAR boundary cells and view cells (Sec. III-B), a pose-cell
continuous attractor network (Sec. III-C) and a cognitive map (Eq. 12-14).

``Pose2D`` and ``LaserScan`` are loaded on first use, so that importing the package (as the
``bioslam`` command does before it reads its arguments) does not load NumPy: the command
chooses NumPy's BLAS threads first (:func:`bioslam.cli.console_main`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

__all__ = ["LaserScan", "Pose2D", "__version__"]

if TYPE_CHECKING:
    from bioslam.geometry import Pose2D
    from bioslam.scan import LaserScan


def __getattr__(name: str) -> Any:
    if name == "Pose2D":
        from bioslam.geometry import Pose2D

        return Pose2D
    if name == "LaserScan":
        from bioslam.scan import LaserScan

        return LaserScan
    raise AttributeError(f"module 'bioslam' has no attribute {name!r}")
