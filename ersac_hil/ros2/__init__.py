"""The robot seen by ROS 2 tooling: a ROS 2 (Jazzy) publisher over rmw_zenoh's key space and
MCAP episode files, with no ROS installed (``docs/ros2.md``).

``names`` (rmw_zenoh 1.x keys, liveliness tokens, attachments), ``messages`` (telemetry ->
ROS 2 messages, CDR from rosbags' Jazzy typestore), ``recorder`` (MCAP files), ``bridge`` (the
live node), ``stream`` (an episode's messages from the agent's raw records), ``writer`` (the
feed process, a child of the agent, where ``stream``, ``bridge`` and ``recorder`` run),
``feed`` (the agent's side: the queue its cycle and bus hooks feed, and the thread that hands
it on to the feed process).
"""
