"""The MAVLink link to one vehicle: the connection, our HEARTBEAT, the receive loop and the
routing of each message to whoever subscribed to its kind, the command protocol
(COMMAND_LONG retried until its COMMAND_ACK) and waits on the vehicle's answers.

Speaks MAVLink 2 with pymavlink to any connection string (``udpout:host:port``,
``udpin:host:port``, ``/dev/ttyAMA0,921600``...) as a companion computer: HEARTBEAT about
1 Hz (of simulation time) as MAV_TYPE_ONBOARD_CONTROLLER, autopilot INVALID, component 191.

* The target is ``cfg.target_system``, or (0) the first system whose HEARTBEAT comes from an
  autopilot (not a ground station, not a companion); a companion then shares its system id.
* Only messages of the target system are routed; the autopilot's own state (HEARTBEAT of
  the autopilot component, ATTITUDE, LOCAL_POSITION_NED) is kept in :attr:`vehicle`, and
  every component heard (HEARTBEAT) with its MAV_TYPE in :attr:`components`.
* A COMMAND_ACK counts only when it comes from the vehicle and is addressed to us (target
  system / component ours, or 0 as in MAVLink 1): a ground station's ACK is not ours. ACKs
  are kept per (command, component): a camera's ACK is not the autopilot's.
* Bad or hostile input never raises: undecodable bytes (BAD_DATA), receive errors and
  subscribers that raise are counted in :attr:`stats` and logged at most once a second.

Times: waits are in simulation seconds of the mission clock (``clock``); the receive and
tick threads run on the local monotonic clock at the clock's scale. Resources (connection,
threads) are held in an :class:`~contextlib.ExitStack`: ``with VehicleLink(...) as link``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from agent.clock import Clock, WallClock
from agent.flight.driver_types import DriverConfig, FlightError, VehicleState, split_baud
from agent.flight.flavours import Autopilot, flavour, flavour_of_heartbeat
from agent.wire.mavlink import mavlink, mavutil

_log = logging.getLogger(f"viscover.{__name__}")

Handler = Callable[[Any], None]
#: HEARTBEAT types that are never the vehicle's autopilot.
_NOT_AUTOPILOT = (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)


@dataclass
class LinkStats:
    """Inbound counters: messages of the target system, of other systems, undecodable ones
    (BAD_DATA), receive errors, and subscriber exceptions."""

    received: int = 0
    foreign: int = 0
    bad: int = 0
    rx_errors: int = 0
    handler_errors: int = 0


class VehicleLink:
    """One vehicle's MAVLink link (see the module docstring). ``start()`` begins receiving
    and sending HEARTBEATs; ``close()`` stops both and closes the connection."""

    def __init__(self, connection: str, config: DriverConfig | None = None,
                 clock: Clock | None = None, source_system: int | None = None) -> None:
        self.cfg = config or DriverConfig()
        self.clock = clock or WallClock()
        self.target_system = self.cfg.target_system
        sysid = (self.target_system or 1) if source_system is None else source_system
        self._fixed_source = source_system is not None
        device, baud = split_baud(connection)
        try:
            self.conn: Any = mavutil.mavlink_connection(
                device, baud=baud, source_system=sysid,
                source_component=self.cfg.source_component, autoreconnect=True)
        except (OSError, ValueError) as e:
            raise FlightError(f"cannot open MAVLink connection {connection!r}: {e}") from None
        self._stack = contextlib.ExitStack()
        self._stack.callback(self._close_connection)
        self.vehicle = VehicleState()
        self.components: dict[int, int] = {}  #: component → MAV_TYPE, from HEARTBEATs
        self.stats = LinkStats()
        self.cond = threading.Condition()  #: notified after every routed message
        self._send_lock = threading.Lock()
        self._subs: dict[str, list[Handler]] = {}
        self._tickers: list[Callable[[], None]] = []
        self._acks: dict[int, dict[int, int]] = {}  # command -> component -> MAV_RESULT
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._last_complaint = -1e9

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> VehicleLink:
        """Start the receive thread and the tick thread (HEARTBEATs, tickers)."""
        if self._threads:
            return self
        for name, fn in (("mav-rx", self._rx_loop), ("mav-tick", self._tick_loop)):
            th = threading.Thread(target=fn, name=name, daemon=True)
            th.start()
            self._threads.append(th)
        self._stack.callback(self._join_threads)
        return self

    def close(self) -> None:
        """Stop the threads and close the connection (idempotent)."""
        self._stop.set()
        with self.cond:
            self.cond.notify_all()
        self._stack.close()

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._stop.is_set()

    def _join_threads(self) -> None:
        for th in self._threads:
            if th is not threading.current_thread():
                th.join(5.0)
        self._threads.clear()

    def _close_connection(self) -> None:
        with contextlib.suppress(OSError):
            self.conn.close()

    def __enter__(self) -> VehicleLink:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- identity -------------------------------------------------------------------------
    @property
    def own_system(self) -> int:
        """Our MAVLink system id (the vehicle's, once adopted)."""
        return int(self.conn.mav.srcSystem)

    @property
    def own_component(self) -> int:
        """Our MAVLink component id (191, onboard computer, by default)."""
        return int(self.cfg.source_component)

    @property
    def configured(self) -> Autopilot:
        """The flavour named in the settings (``cfg.autopilot``)."""
        return flavour(self.cfg.autopilot)

    @property
    def flavour(self) -> Autopilot:
        """The vehicle's flavour from its HEARTBEAT, else the configured one."""
        return flavour_of_heartbeat(self.vehicle.autopilot) or self.configured

    def ms(self) -> int:
        """Our time_boot_ms: the mission clock [ms], wrapped to 32 bits."""
        return int(max(self.clock.now(), 0.0) * 1000.0) & 0xFFFFFFFF

    # -- routing --------------------------------------------------------------------------
    def subscribe(self, kinds: str | Iterable[str], handler: Handler) -> Callable[[], None]:
        """Call ``handler(msg)`` on the receive thread for every message of the target
        system of these kinds ('*' for all); returns the function that unsubscribes. A
        handler must not block; one that raises is counted, never fatal."""
        names = [kinds] if isinstance(kinds, str) else list(kinds)
        with self.cond:
            for k in names:
                self._subs.setdefault(k, []).append(handler)

        def unsubscribe() -> None:
            with self.cond:
                for k in names:
                    with contextlib.suppress(ValueError):
                        self._subs.get(k, []).remove(handler)

        return unsubscribe

    def add_ticker(self, fn: Callable[[], None]) -> Callable[[], None]:
        """Call ``fn()`` about 20 times a second (wall) on the tick thread; returns the
        function that removes it. Exceptions are counted and logged, never fatal."""
        with self.cond:
            self._tickers.append(fn)

        def remove() -> None:
            with self.cond, contextlib.suppress(ValueError):
                self._tickers.remove(fn)

        return remove

    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.05)
            except Exception as e:
                self.stats.rx_errors += 1
                self._complain("receive failed: %s", e)
                self._stop.wait(0.05)
                continue
            if msg is not None:
                self.on_message(msg)

    def on_message(self, msg: Any) -> None:
        """Route one received message (the receive loop's body; tests call it directly)."""
        try:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                self.stats.bad += 1
                return
            self._adopt(msg, kind)
            if msg.get_srcSystem() != self.target_system:
                self.stats.foreign += 1
                return
            self.stats.received += 1
            self._record(msg, kind)
        except Exception as e:
            self.stats.bad += 1
            self._complain("undecodable message: %s", e)
            return
        with self.cond:
            handlers = [*self._subs.get(kind, ()), *self._subs.get("*", ())]
        for h in handlers:
            try:
                h(msg)
            except Exception:
                self.stats.handler_errors += 1
                if self._may_complain():
                    _log.exception("handler of %s failed", kind)
        with self.cond:
            self.cond.notify_all()

    def _adopt(self, msg: Any, kind: str) -> None:
        """Adopt the first autopilot's system id when none is configured."""
        if kind == "HEARTBEAT" and self.target_system == 0 \
                and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID \
                and msg.type not in _NOT_AUTOPILOT:
            self.target_system = int(msg.get_srcSystem())
            if not self._fixed_source:
                self.conn.mav.srcSystem = self.target_system  # a companion shares its sysid

    def _record(self, msg: Any, kind: str) -> None:
        """Keep the autopilot's own state and our COMMAND_ACKs."""
        v = self.vehicle
        if kind == "HEARTBEAT":
            self.components[int(msg.get_srcComponent())] = int(msg.type)
            if msg.type in _NOT_AUTOPILOT or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
                return  # a ground station, a companion, a camera or a gimbal
            with self.cond:
                v.heartbeat_wall = time.monotonic()
                v.armed = bool(int(msg.base_mode) & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                v.custom_mode = int(msg.custom_mode)
                v.autopilot = int(msg.autopilot)
        elif kind == "COMMAND_ACK":
            if self.ack_is_ours(msg):
                with self.cond:
                    self._acks.setdefault(int(msg.command), {})[
                        int(msg.get_srcComponent())] = int(msg.result)
        elif kind == "ATTITUDE":
            v.attitude = (float(msg.roll), float(msg.pitch), float(msg.yaw))
        elif kind == "LOCAL_POSITION_NED":
            v.position_ned = (float(msg.x), float(msg.y), float(msg.z),
                              float(msg.vx), float(msg.vy), float(msg.vz))

    def ack_is_ours(self, msg: Any) -> bool:
        """A COMMAND_ACK addressed to this companion (target 0 = unset, MAVLink 1)."""
        ts, tc = int(getattr(msg, "target_system", 0)), int(getattr(msg, "target_component", 0))
        return ts in (0, self.own_system) and tc in (0, self.own_component)

    def _may_complain(self) -> bool:
        now = time.monotonic()
        if now - self._last_complaint < 1.0:
            return False
        self._last_complaint = now
        return True

    def _complain(self, fmt: str, *args: object) -> None:
        if self._may_complain():
            _log.warning(fmt + " (rx errors %d, bad %d)", *args, self.stats.rx_errors,
                         self.stats.bad)

    # -- send -------------------------------------------------------------------------------
    def send(self, fn: Callable[[Any], object]) -> None:
        """Call ``fn(mav)`` (pymavlink's MAVLink object) under the send lock."""
        with self._send_lock:
            fn(self.conn.mav)

    def send_heartbeat(self) -> None:
        """HEARTBEAT as MAV_TYPE_ONBOARD_CONTROLLER, autopilot INVALID."""
        self.send(lambda mav: mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                                 mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                                 mavlink.MAV_STATE_ACTIVE))

    def _tick_loop(self) -> None:
        last_hb = -1e9
        while not self._stop.is_set():
            now = time.monotonic()
            if now - last_hb >= self.clock.wall(1.0):
                last_hb = now
                try:
                    self.send_heartbeat()
                except Exception as e:
                    self._complain("heartbeat not sent: %s", e)
            with self.cond:
                tickers = list(self._tickers)
            for fn in tickers:
                try:
                    fn()
                except Exception:
                    self.stats.handler_errors += 1
                    if self._may_complain():
                        _log.exception("ticker failed")
            self._stop.wait(0.05)

    def send_command(self, command: int, *params: float, component: int | None = None,
                     confirmation: int = 0) -> None:
        """COMMAND_LONG to ``component`` (default the autopilot's), without waiting."""
        p = [float(x) for x in [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]]
        comp = self.cfg.target_component if component is None else component
        self.send(lambda mav: mav.command_long_send(self.target_system, comp, command,
                                                    confirmation, *p))

    def forget_ack(self, command: int, component: int | None = None) -> None:
        """Drop the kept ACKs of ``command`` (of one component, or all)."""
        with self.cond:
            if component is None or component == 0:
                self._acks.pop(command, None)
            else:
                self._acks.get(command, {}).pop(component, None)

    def ack_of(self, command: int, component: int | None = None) -> int | None:
        """The kept MAV_RESULT of ``command`` from ``component`` (None/0: any component);
        None while none came (or only IN_PROGRESS)."""
        with self.cond:
            got = self._acks.get(command, {})
            if component is None or component == 0:
                results = [r for r in got.values() if r != mavlink.MAV_RESULT_IN_PROGRESS]
                return results[0] if results else None
            r = got.get(component)
            return None if r is None or r == mavlink.MAV_RESULT_IN_PROGRESS else r

    def command(self, command: int, *params: float, component: int | None = None,
                retries: int | None = None, timeout_s: float | None = None) -> int:
        """COMMAND_LONG retried (confirmation counting up) until its COMMAND_ACK; returns
        the MAV_RESULT. FlightError after ``retries`` tries of ``timeout_s`` [s sim] each."""
        comp = self.cfg.target_component if component is None else component
        tries = self.cfg.retries if retries is None else retries
        wait = self.cfg.ack_timeout_s if timeout_s is None else timeout_s
        for attempt in range(tries):
            self.forget_ack(command, comp)
            self.send_command(command, *params, component=comp, confirmation=attempt)
            if self.wait(lambda: self.ack_of(command, comp) is not None, wait):
                result = self.ack_of(command, comp)
                assert result is not None
                return result
        raise FlightError(f"no COMMAND_ACK for command {command} after {tries} tries")

    def request_message(self, message_id: int, *params: float, component: int | None = None,
                        retries: int | None = None, timeout_s: float | None = None) -> int:
        """MAV_CMD_REQUEST_MESSAGE (512) for ``message_id``; returns the ACK's MAV_RESULT."""
        return self.command(mavlink.MAV_CMD_REQUEST_MESSAGE, float(message_id), *params,
                            component=component, retries=retries, timeout_s=timeout_s)

    # -- waits ------------------------------------------------------------------------------
    def wait(self, pred: Callable[[], bool], timeout_sim: float) -> bool:
        """Wait until ``pred()`` (checked under the condition), at most ``timeout_sim`` [s
        sim]; False on timeout or once closed."""
        deadline = self.clock.now() + timeout_sim
        with self.cond:
            while not pred():
                left = deadline - self.clock.now()
                if left <= 0 or self._stop.is_set():
                    return pred()
                self.cond.wait(min(0.05, self.clock.wall(left)))
        return True

    def wait_heartbeat(self) -> None:
        """Wait for the vehicle's HEARTBEAT; FlightError after ``heartbeat_timeout_s``."""
        self.send_heartbeat()
        if not self.wait(lambda: self.vehicle.heartbeat_wall > 0, self.cfg.heartbeat_timeout_s):
            who = f"system {self.target_system}" if self.target_system else "any vehicle"
            raise FlightError(f"no HEARTBEAT from {who} within "
                              f"{self.cfg.heartbeat_timeout_s:g} s")

    def wait_heartbeat_showing(self, pred: Callable[[VehicleState], bool], what: str) -> None:
        """Wait for a HEARTBEAT newer than now whose state satisfies ``pred``."""
        since = time.monotonic()
        ok = self.wait(lambda: self.vehicle.heartbeat_wall > since and pred(self.vehicle),
                       self.cfg.heartbeat_timeout_s)
        if not ok:
            raise FlightError(f"vehicle HEARTBEAT never showed {what}")
