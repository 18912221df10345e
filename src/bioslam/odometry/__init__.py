"""LiDAR odometry (paper Sec. III-A, Eq. 1-4): scan-to-local-map matching, the state machine.

Follows Hector SLAM (Kohlbrecher et al. 2011), the method the paper cites: every scan is
matched against a local log-odds occupancy grid by maximising the summed map function M* at the
scan endpoints (Eq. 3), coarse to fine over a map pyramid, starting from a constant-velocity
prediction. The map is a window that scrolls with the robot, so memory is constant however long
the run. The matching itself lives in :mod:`bioslam.matching` (Gauss-Newton, the searches,
de-skewing, pairwise registration) and its settings in :mod:`bioslam.odometry_config`; this
package decides, scan by scan, where to start, when a match has failed, what to search and what
to keep, one concept a module:

- :mod:`~bioslam.odometry.lidar_odometry`: :class:`LidarOdometry`, the state machine of one
  update (prediction, match, the motion model's and the scores' bookkeeping);
- :mod:`~bioslam.odometry.local_map`: the map pyramid scans are fused into, and the submaps
  of sparse scans;
- :mod:`~bioslam.odometry.guards`: the trusted prediction's match checked against the map;
- :mod:`~bioslam.odometry.search`: the starts searched when the prediction is not trusted;
- :mod:`~bioslam.odometry.choice`: which of the matches the scan keeps;
- :mod:`~bioslam.odometry.sweep`: the turn during a 360° scan's sweep, measured on the scan
  where the motion model cannot give it (after a gap, on a thinned log).

Frames: the sensor frame is taken as the robot frame (no extrinsic offset). The pose of a scan
is the pose at ``scan.stamp`` (the first beam, as in ROS); with per-beam timing the endpoints
are de-skewed to that instant with the current constant-velocity estimate (after a gap, on
a 360° scan, with the turn rate measured on the scan).

No file or terminal I/O here.
"""

from bioslam.matching.deskew import deskew_points, se2_exp, se2_log
from bioslam.matching.gauss_newton import MatchReport, geometric_conditioning, match_scan_to_map
from bioslam.matching.registration import (
    RegistrationConfig,
    RegistrationQuality,
    densify_scan,
    register_scans,
)
from bioslam.odometry.lidar_odometry import LidarOdometry
from bioslam.odometry.search import turned_windows
from bioslam.odometry_config import OdometryConfig

__all__ = [
    "LidarOdometry",
    "MatchReport",
    "OdometryConfig",
    "RegistrationConfig",
    "RegistrationQuality",
    "densify_scan",
    "deskew_points",
    "geometric_conditioning",
    "match_scan_to_map",
    "register_scans",
    "se2_exp",
    "se2_log",
    "turned_windows",
]
