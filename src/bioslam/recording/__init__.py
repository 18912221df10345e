"""Looking inside a run: an MCAP recording and a live Foxglove view of scans, map and neurons.

``bioslam run ... --record OUT.mcap`` writes every scan, the odometry and SLAM poses, the
transform tree ``map -> odom -> base_link``, the occupancy map, the cognitive map, the
boundary-cell, view-cell and pose-cell activity and log messages into one MCAP file on the
log's clock; ``--live [PORT]`` serves the same channels over the Foxglove WebSocket protocol
while the run goes. The Foxglove layout ``docs/foxglove/bioslam_layout.json`` shows them all.

Modules: :mod:`.topics` (topic names, frames and schemas), :mod:`.rates` (what goes out how
often), :mod:`.tap` (the run's observer: copies out what the channels need), :mod:`.session`
(the command's flags; one writing process per output), :mod:`.worker` (that process),
:mod:`.recorder` and :mod:`.messages` (items to Foxglove messages), :mod:`.layout` (the layout
file), :mod:`.reading` (summary and decoding of a recorded file) and :mod:`.render` (a picture
of a recorded map). The run's side (:mod:`.topics`, :mod:`.rates`, :mod:`.tap`,
:mod:`.session`) needs none of the optional ``foxglove`` extra (``pip install
"bioslam[foxglove]"``); the writing process and the readers do.
"""
