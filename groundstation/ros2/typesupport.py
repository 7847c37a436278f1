"""The ROS 2 message types the bridge speaks, and their CDR, from ``rosbags`` (its message
definitions of ROS 2 Jazzy; no hand-written CDR): serialisation, type hashes (RIHS01, computed
offline from the definitions) and the message definitions a bag stores.

Every type here has the same definition in Humble and Jazzy (``tests/test_ros2_convert.py``
checks it), so one store serves both; only the hash written in keys and tokens differs
(:func:`groundstation.ros2.rmw.type_hash_for`).
"""

from __future__ import annotations

from functools import cache
from typing import Final

from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

POSE_STAMPED: Final = "geometry_msgs/msg/PoseStamped"
TF_MESSAGE: Final = "tf2_msgs/msg/TFMessage"
MARKER_ARRAY: Final = "visualization_msgs/msg/MarkerArray"
DIAGNOSTIC_ARRAY: Final = "diagnostic_msgs/msg/DiagnosticArray"
LOG: Final = "rcl_interfaces/msg/Log"
STRING: Final = "std_msgs/msg/String"
#: Every type the bridge publishes or subscribes to.
TYPES: Final = (POSE_STAMPED, TF_MESSAGE, MARKER_ARRAY, DIAGNOSTIC_ARRAY, LOG, STRING)
#: The store whose definitions are used (and the other one they are checked against).
STORE: Final = Stores.ROS2_JAZZY


@cache
def typestore() -> Typestore:
    """The rosbags type store of :data:`STORE` (built once)."""
    return get_typestore(STORE)


def serialize(msg: object, typename: str) -> bytes:
    """``msg`` (a rosbags message of ``typename``) as little-endian CDR with its 4-byte
    encapsulation header, as rmw_zenoh sends it."""
    return bytes(typestore().serialize_cdr(msg, typename, little_endian=True))


def deserialize(data: bytes, typename: str) -> object:
    """A CDR payload of ``typename`` as a rosbags message; raises rosbags' ``SerdeError`` (or
    a KeyError for an unknown type) when it is not one."""
    return typestore().deserialize_cdr(data, typename)


@cache
def rihs01(typename: str) -> str:
    """The RIHS01 type hash of ``typename`` (REP-2016), e.g. ``RIHS01_df66...`` for
    ``std_msgs/msg/String``."""
    return typestore().hash_rihs01(typename)


@cache
def msgdef(typename: str) -> str:
    """The ``.msg`` definition of ``typename`` with its dependencies, as rosbag2 stores it."""
    return typestore().generate_msgdef(typename, ros_version=2)[0]
