"""Scan matching: Gauss-Newton on the map function (Eq. 1-4), searches for its start, and
the de-skewing of moving scans.

- :mod:`~bioslam.matching.gauss_newton`: Eq. 3-4 by Gauss-Newton over a map pyramid.
- :mod:`~bioslam.matching.correlative`: exhaustive lattice search (small windows).
- :mod:`~bioslam.matching.branch_and_bound`: exhaustive-equivalent wide-window search by
  branch and bound over max-pooled grids, reporting the best distinct rival.
- :mod:`~bioslam.matching.deskew`: SE(2) twists and per-beam de-skewing.
- :mod:`~bioslam.matching.registration`: one scan against another (loop closures).
"""
