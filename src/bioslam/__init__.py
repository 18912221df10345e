"""bioslam: biologically-inspired 2D LiDAR SLAM (Zhuang et al.).

LiDAR odometry (Sec. III-A), LiDAR boundary cells and view cells (Sec. III-B), a pose-cell
continuous attractor network (Sec. III-C) and a cognitive map (Eq. 12-14).
"""

from bioslam.geometry import Pose2D
from bioslam.scan import LaserScan

__version__ = "0.1.0"

__all__ = ["LaserScan", "Pose2D", "__version__"]
