"""What the ground station publishes: motion capture, its health, the landmark set and the
shared clock (versioned msgspec Structs, msgpack through :class:`agent.wire.codec.Codec`).
Agents and observers read them; the messages agents exchange among themselves are in
:mod:`agent.wire.peer`.

Keys (builders in :mod:`agent.wire.keys`):

================================  ============================================
``viscover/<m>/mocap/<drone>``     :class:`MocapPose` from the ground station
``viscover/<m>/mocap_status/<d>``  :class:`MocapStatus` (stale / missing bodies)
``viscover/<m>/landmarks``         :class:`LandmarkSet` (``keys.landmarks_key``)
``viscover/<m>/clock``               :class:`ClockMsg`
================================  ============================================

Frames: world ENU [m], body FLU; quaternions (w, x, y, z) = R_ENU←FLU; times are simulation
seconds of the shared clock.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from agent.wire.codec import Codec

#: Bounded fields (they come from the network): short names, non-negative sequence numbers.
Name = Annotated[str, msgspec.Meta(max_length=64)]
Seq = Annotated[int, msgspec.Meta(ge=0, le=2**62)]


class MocapPose(msgspec.Struct, kw_only=True):
    """One motion-capture pose: drone id, sequence number, capture time t [s sim], position p
    [m ENU], attitude q (w, x, y, z) R_ENU←FLU, velocity v [m/s ENU], world frame id, source."""

    drone: Name
    seq: Seq
    t: float
    p: list[float]
    q: list[float]
    v: list[float]
    frame_id: Name = "world_enu"
    source: Name = "sim"
    schema: int = 1


class MocapStatus(msgspec.Struct, kw_only=True):
    """Health of one drone's rigid body: ``ok``, ``stale`` (last seen ``age`` s ago) or
    ``missing`` (never seen); published when it changes and once a second."""

    drone: Name
    state: Name
    age: float
    t: float
    schema: int = 1


class LandmarkSet(msgspec.Struct, kw_only=True):
    """The mission's landmarks: ids, positions q (m, 3) [m ENU], unit normals u (m, 3)."""

    mission: Name
    ids: list[int]
    q: list[list[float]]
    u: list[list[float]]
    schema: int = 1


class ClockMsg(msgspec.Struct, kw_only=True):
    """The shared simulation clock: time t [s sim], time scale [s sim / s wall], sequence."""

    t: float
    time_scale: float
    seq: Seq = 0
    schema: int = 1


MOCAP_CODEC: Codec[MocapPose] = Codec(MocapPose)
STATUS_CODEC: Codec[MocapStatus] = Codec(MocapStatus)
LANDMARKS_CODEC: Codec[LandmarkSet] = Codec(LandmarkSet)
CLOCK_CODEC: Codec[ClockMsg] = Codec(ClockMsg)
