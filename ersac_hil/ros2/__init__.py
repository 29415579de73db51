"""The robot seen by ROS 2 tooling: a ROS 2 (Jazzy) publisher over rmw_zenoh's key space and
MCAP episode files, with no ROS installed (``docs/ros2.md``).

``names`` (rmw_zenoh 1.x keys, liveliness tokens, attachments), ``messages`` (telemetry ->
ROS 2 messages, CDR from rosbags' Jazzy typestore), ``recorder`` (MCAP files, written by the ``writer``
process), ``bridge`` (the live node), ``feed`` (the thread the agent's cycle and bus hooks feed).
"""
