"""Figures of a bioslam run (matplotlib, written as PNG files without a display).

``figures`` holds the pipeline's pictures (cognitive map, active view over time, position error
over time, mapping progress as the paper's Fig. 5, occupancy map); ``boundary`` the boundary-cell
pictures. Plot functions take plain data, write one file and return its path; they never compute
SLAM state themselves.
"""

#: What the figures call the trajectory a run is evaluated against, unless told otherwise.
GROUND_TRUTH = "ground truth"
#: ... and a log's corrected poses: another SLAM system's estimate, with errors of its own.
LOG_REFERENCE = "log's corrected poses"
