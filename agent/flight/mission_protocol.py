"""The MAVLink mission protocol (mavlink.io "Mission Protocol") for any mission type, over a
:class:`~agent.flight.link.VehicleLink`: upload and download of MISSION_ITEM_INT lists.

Upload: we send MISSION_COUNT (count, mission_type); the vehicle asks for each item with
MISSION_REQUEST_INT or MISSION_REQUEST (ArduPilot's MissionItemProtocol sends
MISSION_REQUEST, PX4's mavlink_mission sends MISSION_REQUEST_INT in int mode: both are
answered with MISSION_ITEM_INT, which both accept), in any order and possibly repeated; it
ends with MISSION_ACK (MAV_MISSION_ACCEPTED, or the reason it refused). With no request
within ``item_timeout_s`` the count is sent again, up to ``retries`` times.

Download: MISSION_REQUEST_LIST → MISSION_COUNT → MISSION_REQUEST_INT per item (each retried)
→ MISSION_ITEM_INT → our MISSION_ACK.

Only messages of the vehicle's autopilot component, of the transfer's mission type and
addressed to us (or to 0) take part; anything else is ignored. Times in simulation seconds.
"""

from __future__ import annotations

import queue
from dataclasses import dataclass
from typing import Any

from agent.flight.driver_types import FlightError
from agent.flight.link import VehicleLink
from agent.wire.mavlink import mavlink

_KINDS = ("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK", "MISSION_COUNT",
          "MISSION_ITEM_INT")


@dataclass(frozen=True)
class MissionItem:
    """One MISSION_ITEM_INT's content: frame (MAV_FRAME), command (MAV_CMD), param1-4, x, y
    (latitude, longitude [degE7] in global frames), z (altitude [m])."""

    command: int
    x: int = 0
    y: int = 0
    z: float = 0.0
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    frame: int = mavlink.MAV_FRAME_GLOBAL
    autocontinue: int = 0

    def same_as(self, other: MissionItem) -> bool:
        """The same command, first parameter and position (what a vehicle stores of a fence
        item; it may report another frame and altitude)."""
        return (self.command, self.x, self.y) == (other.command, other.x, other.y) and \
            abs(self.param1 - other.param1) < 1e-3


def result_name(code: int) -> str:
    """MAV_MISSION_RESULT's name, e.g. 'MAV_MISSION_UNSUPPORTED_FRAME'."""
    entry = mavlink.enums.get("MAV_MISSION_RESULT", {}).get(code)
    return entry.name if entry is not None else f"MAV_MISSION_RESULT {code}"


class MissionTransfer:
    """Uploads and downloads items of one mission type (e.g. MAV_MISSION_TYPE_FENCE)."""

    def __init__(self, link: VehicleLink, mission_type: int, item_timeout_s: float = 1.5,
                 retries: int = 5) -> None:
        self.link = link
        self.mission_type = mission_type
        self.item_timeout_s = item_timeout_s
        self.retries = retries
        self._inbox: queue.Queue[Any] = queue.Queue()
        self._unsub = link.subscribe(_KINDS, self._on_message)

    def close(self) -> None:
        """Stop listening."""
        self._unsub()

    def _on_message(self, msg: Any) -> None:
        link = self.link
        if msg.get_srcComponent() != link.cfg.target_component \
                or int(getattr(msg, "mission_type", 0)) != self.mission_type \
                or int(msg.target_system) not in (0, link.own_system) \
                or int(msg.target_component) not in (0, link.own_component):
            return
        self._inbox.put(msg)

    def _next(self, timeout_s: float) -> Any | None:
        try:
            return self._inbox.get(timeout=self.link.clock.wall(timeout_s))
        except queue.Empty:
            return None

    def _drain(self) -> None:
        while not self._inbox.empty():
            self._inbox.get_nowait()

    # -- upload -----------------------------------------------------------------------------
    def upload(self, items: list[MissionItem]) -> None:
        """Upload ``items`` (replacing the vehicle's list of this type); FlightError naming
        the vehicle's MAV_MISSION_RESULT, or the silence, if it does not accept them."""
        link, n = self.link, len(items)
        self._drain()
        link.send(lambda mav: mav.mission_count_send(
            link.target_system, link.cfg.target_component, n, self.mission_type))
        silent = 0
        while True:
            msg = self._next(self.item_timeout_s)
            if msg is None:
                silent += 1
                if silent > self.retries:
                    raise FlightError(f"mission upload (type {self.mission_type}): the vehicle "
                                      f"stopped answering after {self.retries} retries")
                link.send(lambda mav: mav.mission_count_send(
                    link.target_system, link.cfg.target_component, n, self.mission_type))
                continue
            silent = 0
            kind = msg.get_type()
            if kind == "MISSION_ACK":
                if int(msg.type) != mavlink.MAV_MISSION_ACCEPTED:
                    raise FlightError(f"mission upload (type {self.mission_type}) refused: "
                                      f"{result_name(int(msg.type))}")
                return
            if kind in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
                seq = int(msg.seq)
                if 0 <= seq < n:
                    self._send_item(seq, items[seq])

    def _send_item(self, seq: int, it: MissionItem) -> None:
        link = self.link
        link.send(lambda mav: mav.mission_item_int_send(
            link.target_system, link.cfg.target_component, seq, it.frame, it.command, 0,
            it.autocontinue, it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z,
            self.mission_type))

    # -- download ---------------------------------------------------------------------------
    def download(self) -> list[MissionItem]:
        """The vehicle's items of this type; FlightError if it does not answer."""
        link = self.link
        self._drain()
        count: int | None = None
        for _ in range(self.retries):
            link.send(lambda mav: mav.mission_request_list_send(
                link.target_system, link.cfg.target_component, self.mission_type))
            msg = self._await("MISSION_COUNT", None)
            if msg is not None:
                count = int(msg.count)
                break
        if count is None:
            raise FlightError(f"mission download (type {self.mission_type}): no MISSION_COUNT")
        items: list[MissionItem] = []
        for seq in range(count):
            items.append(self._fetch(seq))
        link.send(lambda mav: mav.mission_ack_send(
            link.target_system, link.cfg.target_component, mavlink.MAV_MISSION_ACCEPTED,
            self.mission_type))
        return items

    def _fetch(self, seq: int) -> MissionItem:
        link = self.link
        for _ in range(self.retries):
            link.send(lambda mav: mav.mission_request_int_send(
                link.target_system, link.cfg.target_component, seq, self.mission_type))
            msg = self._await("MISSION_ITEM_INT", seq)
            if msg is not None:
                return MissionItem(int(msg.command), int(msg.x), int(msg.y), float(msg.z),
                                   float(msg.param1), float(msg.param2), float(msg.param3),
                                   float(msg.param4), int(msg.frame), int(msg.autocontinue))
        raise FlightError(f"mission download (type {self.mission_type}): no item {seq}")

    def _await(self, kind: str, seq: int | None) -> Any | None:
        """The next message of ``kind`` (and ``seq``) within ``item_timeout_s``; a
        MISSION_ACK with an error ends the download (FlightError)."""
        deadline = self.link.clock.now() + self.item_timeout_s
        while (left := deadline - self.link.clock.now()) > 0:
            msg = self._next(left)
            if msg is None:
                return None
            if msg.get_type() == "MISSION_ACK" and int(msg.type) != mavlink.MAV_MISSION_ACCEPTED:
                raise FlightError(f"mission download (type {self.mission_type}) refused: "
                                  f"{result_name(int(msg.type))}")
            if msg.get_type() == kind and (seq is None or int(msg.seq) == seq):
                return msg
        return None
