"""The ROS names of a mission: topics under one namespace (default ``/viscover``), frame ids,
and drone ids made valid ROS name tokens.

==================================  ====================================  =====================
topic                               type                                  content
==================================  ====================================  =====================
``<ns>/<drone>/pose``               geometry_msgs/msg/PoseStamped         the agent's camera pose
``<ns>/<drone>/mocap``              geometry_msgs/msg/PoseStamped         the ground station's mocap
``/tf``                             tf2_msgs/msg/TFMessage                world → drone → camera
``<ns>/landmarks``                  visualization_msgs/msg/MarkerArray    coloured by owner
``<ns>/captures``                   visualization_msgs/msg/MarkerArray    by capture state
``<ns>/frusta``                     visualization_msgs/msg/MarkerArray    camera frusta, labels
``<ns>/status``                     diagnostic_msgs/msg/DiagnosticArray   per drone and mission
``<ns>/events``                     rcl_interfaces/msg/Log                events, capture log
``<ns>/land``, ``<ns>/stop``        std_msgs/msg/String (subscribed)      operator commands
==================================  ====================================  =====================

A ROS name token holds letters, digits and underscores, does not start with a digit and has
no ``__`` (ROS 2's topic name rules); a viscover id may hold ``-`` and start with a digit, so
:func:`drone_token` maps it (``-`` → ``_``, a leading digit gets ``d``, runs of ``_`` become
one). Two drones whose tokens collide are refused at start (:func:`drone_tokens`).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

DEFAULT_NAMESPACE: Final = "/viscover"
#: The world frame (ENU) every message is expressed in.
WORLD: Final = "world"
TF_TOPIC: Final = "/tf"
_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def drone_token(drone: str) -> str:
    """A viscover id (``[A-Za-z0-9_-]{1,32}``) as a ROS name token (module docstring)."""
    tok = re.sub(r"_+", "_", drone.replace("-", "_"))
    return f"d{tok}" if tok[:1].isdigit() else tok


def drone_tokens(ids: Iterable[str]) -> dict[str, str]:
    """{id: token} of the mission's drones; ValueError naming two ids whose tokens collide."""
    out: dict[str, str] = {}
    seen: dict[str, str] = {}
    for d in ids:
        tok = drone_token(d)
        if tok in seen and seen[tok] != d:
            raise ValueError(f"drones {seen[tok]!r} and {d!r} both map to the ROS name {tok!r}")
        seen[tok] = d
        out[d] = tok
    return out


def check_namespace(ns: str) -> str:
    """``ns`` if it is an absolute ROS namespace (``/a/b``, tokens as in the module
    docstring, no trailing ``/``); ValueError saying what is wrong otherwise."""
    parts = ns.split("/")
    if not ns.startswith("/") or ns == "/" or ns.endswith("/"):
        raise ValueError(f"namespace {ns!r} must start with / and not end with one, e.g. "
                         f"{DEFAULT_NAMESPACE}")
    for tok in parts[1:]:
        if not _TOKEN.fullmatch(tok) or "__" in tok:
            raise ValueError(f"namespace {ns!r}: {tok!r} is not a ROS name token (letters, "
                             "digits, _; not starting with a digit; no __)")
    return ns


@dataclass(frozen=True)
class Names:
    """Topic names and frame ids of one mission under namespace ``ns``."""

    ns: str = DEFAULT_NAMESPACE

    def pose(self, token: str) -> str:
        """The agent's camera pose topic of drone ``token``."""
        return f"{self.ns}/{token}/pose"

    def mocap(self, token: str) -> str:
        """The ground station's mocap pose topic of drone ``token``."""
        return f"{self.ns}/{token}/mocap"

    @property
    def landmarks(self) -> str:
        """Landmarks coloured by owner."""
        return f"{self.ns}/landmarks"

    @property
    def captures(self) -> str:
        """An inspection's landmarks coloured by capture state."""
        return f"{self.ns}/captures"

    @property
    def frusta(self) -> str:
        """Camera frusta and labels."""
        return f"{self.ns}/frusta"

    @property
    def status(self) -> str:
        """Per-drone and mission diagnostics."""
        return f"{self.ns}/status"

    @property
    def events(self) -> str:
        """Mission events and the capture log."""
        return f"{self.ns}/events"

    def command(self, kind: str) -> str:
        """The subscribed topic of operator command ``kind`` (land, stop)."""
        return f"{self.ns}/{kind}"

    @staticmethod
    def body_frame(token: str) -> str:
        """The body frame (FLU) of drone ``token``."""
        return token

    @staticmethod
    def camera_frame(token: str) -> str:
        """The camera frame of drone ``token``."""
        return f"{token}/camera"
