"""ROS 2 tools see the mission: ``viscover ros2-bridge`` republishes what an observer hears as
ROS 2 topics that rmw_zenoh nodes discover (rviz2, ``ros2 topic``, ``ros2 bag``), and writes
ROS 2 bags; pure Python (``rosbags`` for the message definitions, CDR and type hashes), no ROS
installed. Needs the ``ros2`` extra (``pip install 'viscover[ros2]'``).

Pure parts: :mod:`~groundstation.ros2.rmw` (rmw_zenoh's keys, liveliness tokens, QoS string,
GIDs, attachments), :mod:`~groundstation.ros2.names` (topic names, frame ids),
:mod:`~groundstation.ros2.frames` (ENU / FLU frames, quaternions),
:mod:`~groundstation.ros2.typesupport` (types, CDR and hashes through rosbags),
:mod:`~groundstation.ros2.messages` (viscover → ROS messages),
:mod:`~groundstation.ros2.model` (what to publish when). Adapters:
:mod:`~groundstation.ros2.node` (a ROS node on a Zenoh session), :mod:`~groundstation.ros2.bag`
(a rosbag2 writer), :mod:`~groundstation.ros2.bridge` (the mission in, ROS out),
:mod:`~groundstation.ros2.cli` (``viscover ros2-bridge``).
"""
