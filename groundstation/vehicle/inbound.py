"""What a simulated autopilot makes of the MAVLink it receives, before acting on it.

Every rule here is the autopilot's own (sources read with the ``search`` tool):

* Addressing. ArduPilot (libraries/GCS_MAVLink/MAVLink_routing.cpp, ``forward``) processes a
  message locally when its target system is 0 or its own and its target component 0 or its
  own; anything else is routed, not processed, not acknowledged. PX4
  (src/modules/mavlink/mavlink_receiver.cpp, ``evaluate_target_ok``) takes COMMAND_LONG /
  COMMAND_INT only for its own system id (component its own or 0), except
  MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES and MAV_CMD_REQUEST_PROTOCOL_VERSION, which also take
  system 0 and any component; other commands are ignored without an ACK. For the other
  messages both are treated like ArduPilot's routing (PX4's SET_ATTITUDE_TARGET handler
  checks the same pair).
* MAV_CMD_COMPONENT_ARM_DISARM. ArduPilot (GCS_Common.cpp
  ``handle_command_component_arm_disarm``): arm only for param1 == 1, disarm for param1 == 0,
  anything else (NaN included) MAV_RESULT_UNSUPPORTED; a disarm is forced only by param2 ==
  21196. PX4 (src/modules/commander/Commander.cpp): ``lroundf(param1)`` must be 0 or 1, else
  "Unsupported ARM_DISARM param" (MAV_RESULT_UNSUPPORTED); forced when ``lroundf(param2) ==
  21196``. A NaN param2 (MAVSDK sends every unused parameter as NaN) is therefore "not
  forced" on both: a plain arm or disarm.
* Numbers. The autopilots cast command parameters to integers in C, where a NaN, an
  infinity or a value beyond the type's range has no defined result; this simulator answers
  MAV_RESULT_DENIED ("invalid parameters") for them instead of guessing a value.

:class:`HandlerGuard` is the fleet's last line of defence: an exception that still escapes a
handler is counted and logged (one line per period), and the fleet carries on.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any

from agent.wire.mavlink import FORCE_DISARM_MAGIC
from agent.wire.mavlink import mavlink as mav

_log = logging.getLogger(f"viscover.{__name__}")

#: The autopilot's component id (MAV_COMP_ID_AUTOPILOT1).
AUTOPILOT_COMPONENT = 1
#: PX4 commands that take a broadcast system and any component (``evaluate_target_ok``).
PX4_BROADCAST_COMMANDS = frozenset({mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
                                    mav.MAV_CMD_REQUEST_PROTOCOL_VERSION})
COMMANDS = ("COMMAND_LONG", "COMMAND_INT")

UINT8 = (0, 0xFF)
UINT16 = (0, 0xFFFF)
UINT32 = (0, 0xFFFFFFFF)
INT32 = (-(2**31), 2**31 - 1)
#: MAVLink 2 message ids are 24-bit.
MSG_ID = (0, 0xFFFFFF)


def addressed_to(msg: Any, sysid: int) -> bool:
    """Whether the autopilot ``sysid`` processes ``msg`` by ArduPilot's routing (module
    docstring); PX4 reads messages other than commands the same way.

    Messages without a target (HEARTBEAT, VISION_POSITION_ESTIMATE, ...) are for everyone."""
    system = getattr(msg, "target_system", None)
    if system is None:
        return True
    component = getattr(msg, "target_component", 0)
    return system in (0, sysid) and component in (0, AUTOPILOT_COMPONENT)


def px4_addressed_to(msg: Any, sysid: int) -> bool:
    """Whether the PX4 autopilot ``sysid`` processes ``msg`` (``evaluate_target_ok`` for
    commands, module docstring)."""
    system = getattr(msg, "target_system", None)
    if system is None or msg.get_type() not in COMMANDS:
        return addressed_to(msg, sysid)
    if int(msg.command) in PX4_BROADCAST_COMMANDS:
        return bool(system in (0, sysid))
    return bool(system == sysid and getattr(msg, "target_component", 0)
                in (0, AUTOPILOT_COMPONENT))


def as_int(x: float, bounds: tuple[int, int]) -> int | None:
    """``x`` truncated to an integer (C's cast) if it is finite and within ``bounds``
    (inclusive) once truncated; None otherwise."""
    if not math.isfinite(x):
        return None
    n = int(x)
    return n if bounds[0] <= n <= bounds[1] else None


def _lround(x: float) -> int | None:
    """C's ``lroundf`` (halves away from zero); None where C leaves it unspecified."""
    if not math.isfinite(x) or abs(x) >= 2.0**31:
        return None
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def arm_request(param1: float, param2: float) -> tuple[bool, bool] | None:
    """MAV_CMD_COMPONENT_ARM_DISARM as ArduPilot reads it: (arm, forced), or None for
    MAV_RESULT_UNSUPPORTED (module docstring)."""
    if param1 == 1.0:
        return True, False  # forcing an arm only skips checks this simulator does not run
    if param1 == 0.0:
        return False, param2 == FORCE_DISARM_MAGIC
    return None


def px4_arm_request(param1: float, param2: float) -> tuple[bool, bool] | None:
    """MAV_CMD_COMPONENT_ARM_DISARM as PX4 reads it (``lroundf`` of both; module docstring)."""
    action = _lround(param1)
    if action not in (0, 1):
        return None
    return action == 1, _lround(param2) == FORCE_DISARM_MAGIC


def describe(msg: Any) -> str:
    """What the guard logs for a message: "handling TYPE from sys/comp (command N)"."""
    try:
        label = f"handling {msg.get_type()} from {msg.get_srcSystem()}/{msg.get_srcComponent()}"
    except Exception:  # only a log label; never fail the guard itself
        return f"handling a {type(msg).__name__}"
    command = getattr(msg, "command", None)
    return label if command is None else f"{label} (command {command})"


@dataclass
class HandlerGuard:
    """Counts the exceptions that escaped the vehicles' MAVLink handling (or the fleet's
    loop); logs at most one line per ``period_s`` [s wall] with the count of those not logged
    since (the traceback at DEBUG)."""

    period_s: float = 10.0
    count: int = 0
    _last_log: float = -math.inf
    _unlogged: int = 0

    def failed(self, who: str, what: str, exc: BaseException) -> None:
        """Record one failure of ``who`` (a vehicle, or the fleet) doing ``what`` (e.g.
        :func:`describe` of a message)."""
        self.count += 1
        now = time.monotonic()
        if now - self._last_log < self.period_s:
            self._unlogged += 1
            return
        _log.error("%s: %s failed: %s: %s (%d failures in all, %d not logged since the "
                   "last line); carrying on", who, what, type(exc).__name__, exc, self.count,
                   self._unlogged)
        _log.debug("%s: traceback of that failure", who, exc_info=exc)
        self._last_log, self._unlogged = now, 0
