"""Looking inside a run: an MCAP recording and a live Foxglove view of scans, map and neurons.

``bioslam run ... --record OUT.mcap`` writes every scan, the odometry and SLAM poses, the
transform tree ``map -> odom -> base_link``, the occupancy map, the cognitive map, the
boundary-cell, view-cell and pose-cell activity and log messages into one MCAP file on the
log's clock; ``--live [PORT]`` serves the same channels over the Foxglove WebSocket protocol
while the run goes. The Foxglove layout ``docs/foxglove/bioslam_layout.json`` shows them all.

Modules: :mod:`.topics` (topic names, frames and schemas, no dependencies),
:mod:`.messages` (bioslam state to Foxglove messages), :mod:`.recorder` (what is published
when), :mod:`.session` (opening a file or server for a command), :mod:`.layout` (the layout
file), :mod:`.reading` (summary and decoding of a recorded file) and :mod:`.render` (a PNG of
a recorded map). Only :mod:`.topics` may be imported without the optional ``foxglove`` extra
(``pip install "bioslam[foxglove]"``); the run command imports the rest only when asked to
record or serve.
"""
