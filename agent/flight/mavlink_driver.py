"""MAVLink driver of one drone (thesis section 6.1): poses in, attitude set-points out.

The driver is three parts on one link, opened and closed together:

* :class:`~agent.flight.link.VehicleLink`: the connection, our HEARTBEAT, the receive loop
  routing each message to its subscribers, COMMAND_LONG/COMMAND_ACK, waits;
* :class:`~agent.flight.supervisor.Supervisor`: modes, arming, engage and land through the
  vehicle's flavour (:mod:`agent.flight.flavours`), the vehicle monitor and the release
  rule (a pilot or the autopilot's failsafe always wins);
* :class:`~agent.flight.streamer.SetpointStreamer`: SET_ATTITUDE_TARGET at ``rate_hz``, the
  stale-pose failsafe, the set-point and space guards, mocap forwarded to the EKF;

plus :class:`~agent.flight.params.ParamClient` (the parameter protocol). Field clients
share the link: :mod:`~agent.flight.camera`, :mod:`~agent.flight.gimbal`,
:mod:`~agent.flight.fence`, :mod:`~agent.flight.battery` and
:mod:`~agent.flight.autopilot_pose` (``--pose autopilot``); :mod:`~agent.flight.field` opens
them together. :func:`land_on_signals`: SIGINT/SIGTERM land the drone before exit.

Times are simulation seconds of the mission clock (:class:`agent.clock.Clock`); with a scaled
clock the whole driver runs faster than real time.
"""

from __future__ import annotations

import contextlib
import logging
import signal
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

from agent.clock import Clock
from agent.flight.controllers import FlightController
from agent.flight.driver_types import (
    DriverConfig,
    DriverStats,
    PoseProvider,
    VehicleState,
)
from agent.flight.link import LinkStats, VehicleLink
from agent.flight.monitor import MocapAge, VehicleMonitor, Verdict
from agent.flight.params import ParamClient
from agent.flight.streamer import SetpointStreamer
from agent.flight.supervisor import Supervisor
from agent.net.faults import FaultInjector
from agent.wire.mavlink import GUID_OPTIONS_REAL_THRUST

_log = logging.getLogger(f"viscover.{__name__}")


class MavlinkDriver:
    """One vehicle. ``pose`` supplies poses; ``controller`` turns them into set-points.

    Lifecycle: ``start()`` (threads, heartbeats, stream), ``engage()`` (handshake, raises
    :class:`~agent.flight.driver_types.FlightError`), fly by driving ``controller`` (velocity
    or hold), ``land()``, ``close()`` (or ``with MavlinkDriver(...) as d``).
    ``notify_pose()`` wakes the stream when a pose arrives.
    """

    def __init__(self, connection: str, pose: PoseProvider, controller: FlightController,
                 config: DriverConfig | None = None, clock: Clock | None = None,
                 source_system: int | None = None, faults: FaultInjector | None = None) -> None:
        self.link = VehicleLink(connection, config, clock, source_system)
        self.cfg = self.link.cfg
        self.clock = self.link.clock
        self.faults = faults
        self.controller = controller
        with contextlib.ExitStack() as stack:  # unwound only if a part fails to build
            stack.callback(self.link.close)
            self.params = ParamClient(self.link)
            stack.callback(self.params.close)
            self.supervisor = Supervisor(self.link, self.params)
            stack.callback(self.supervisor.close)
            self.streamer = SetpointStreamer(self.link, self.supervisor, pose, controller,
                                             faults)
            stack.callback(self.streamer.close)
            self._stack = stack.pop_all()  # closed in close(): stream, supervisor, link

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> MavlinkDriver:
        """Start receiving, heartbeats and the set-point stream."""
        self.link.start()
        self.streamer.start()
        return self

    def close(self) -> None:
        """Stop the stream, the supervisor and the link (in that order). Does not land."""
        self._stack.close()

    def __enter__(self) -> MavlinkDriver:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- the parts' state, under the names the rest of the code uses ------------------------
    @property
    def conn(self) -> Any:
        """The pymavlink connection."""
        return self.link.conn

    @property
    def vehicle(self) -> VehicleState:
        """What the vehicle last told us."""
        return self.link.vehicle

    @property
    def link_stats(self) -> LinkStats:
        """Inbound message counters (bad data, foreign systems, subscriber errors)."""
        return self.link.stats

    @property
    def target_system(self) -> int:
        """The vehicle's system id (0 until its first HEARTBEAT when not configured)."""
        return self.link.target_system

    @property
    def pose(self) -> PoseProvider:
        """The pose provider the stream flies on."""
        return self.streamer.pose

    @pose.setter
    def pose(self, provider: PoseProvider) -> None:
        self.streamer.pose = provider

    @property
    def stats(self) -> DriverStats:
        """Set-point stream counters and timings."""
        return self.streamer.stats

    @property
    def mocap_age(self) -> MocapAge:
        """How old the newest pose is (the stale-pose failsafe's rule)."""
        return self.streamer.mocap_age

    @property
    def failsafe_reason(self) -> str:
        """Why the last pose failsafe started (one line)."""
        return self.streamer.failsafe_reason

    @property
    def failsafe_s(self) -> float:
        """How long the last pose failsafe lasted [s sim]."""
        return self.streamer.failsafe_s

    @property
    def on_phase(self) -> Callable[[str], None] | None:
        """Called on every phase change."""
        return self.supervisor.on_phase

    @on_phase.setter
    def on_phase(self, fn: Callable[[str], None] | None) -> None:
        self.supervisor.on_phase = fn

    @property
    def phase(self) -> str:
        """idle | flying | failsafe_hold | released | landing | landed."""
        return self.supervisor.phase

    @phase.setter
    def phase(self, new: str) -> None:
        self.supervisor.phase = new

    @property
    def streaming(self) -> bool:
        """Whether set-points go out."""
        return self.supervisor.streaming

    @streaming.setter
    def streaming(self, on: bool) -> None:
        self.supervisor.streaming = on

    @property
    def monitor(self) -> VehicleMonitor | None:
        """The vehicle monitor (from the vehicle's first HEARTBEAT)."""
        return self.supervisor.monitor

    @property
    def released(self) -> Verdict | None:
        """Why the vehicle left our control (None while ours)."""
        return self.supervisor.released

    # -- commands -------------------------------------------------------------------------
    def wait_heartbeat(self) -> None:
        """Wait for the vehicle's HEARTBEAT; FlightError after ``heartbeat_timeout_s``."""
        self.link.wait_heartbeat()

    def send_heartbeat(self) -> None:
        """HEARTBEAT as MAV_TYPE_ONBOARD_CONTROLLER, autopilot INVALID."""
        self.link.send_heartbeat()

    def set_mode(self, main: int, sub: int = 0) -> None:
        """MAV_CMD_DO_SET_MODE (the flavour's encoding), confirmed by ACK and HEARTBEAT."""
        self.supervisor.set_mode(main, sub)

    def arm(self, armed: bool = True, force: bool = False) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM, confirmed by COMMAND_ACK and HEARTBEAT bit 128."""
        self.supervisor.arm(armed, force)

    def read_params(self, names: list[str], rounds: int | None = None) -> dict[str, float]:
        """Read parameters by name (:meth:`ParamClient.read`)."""
        return self.params.read(names, rounds)

    def ensure_guid_options(self) -> None:
        """ArduPilot: make GUID_OPTIONS include bit 3 (8) so thrust is thrust, and confirm."""
        self.params.ensure_bits("GUID_OPTIONS", GUID_OPTIONS_REAL_THRUST)

    def engage(self) -> None:
        """Handshake (the flavour's steps, then arm); streaming from here on. Raises
        FlightError naming the failed step."""
        self.supervisor.engage(self.streamer.prepare, self.controller.reset)

    def land(self, wait: bool = True, timeout_s: float = 30.0) -> bool:
        """The autopilot's landing mode; True once disarmed (see :meth:`Supervisor.land`)."""
        return self.supervisor.land(wait, timeout_s)

    def watch(self) -> Verdict | None:
        """Check the monitor (see :meth:`Supervisor.watch`)."""
        return self.supervisor.watch()

    def may_command(self) -> bool:
        """Whether mode commands may still be sent (see :meth:`Supervisor.may_command`)."""
        return self.supervisor.may_command()

    def notify_pose(self) -> None:
        """A new pose is available: wake the stream (call from the pose's receive thread)."""
        self.streamer.notify_pose()

    def _step(self) -> None:
        """One stream period, run by hand (tests with a manual clock)."""
        self.streamer.step()


class ShutdownRequested(BaseException):
    """Raised in the main thread by SIGINT/SIGTERM inside :func:`land_on_signals`."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def land_on_signals(driver: MavlinkDriver, timeout_s: float = 30.0,
                    signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)
                    ) -> Iterator[None]:
    """Within the block, SIGINT/SIGTERM raise :class:`ShutdownRequested`; on leaving the block
    (normally, by signal or by error) the drone lands before control returns. Main thread only.
    """

    def handler(signum: int, _frame: FrameType | None) -> None:
        raise ShutdownRequested(signum)

    old = {s: signal.signal(s, handler) for s in signals}
    try:
        yield
    except ShutdownRequested as e:
        _log.warning("%s: landing before exit", e)
    finally:
        for s in signals:  # a second signal during landing is ignored, not fatal
            signal.signal(s, signal.SIG_IGN)
        try:
            driver.land(wait=True, timeout_s=timeout_s)
        finally:
            for s, h in old.items():
                signal.signal(s, h)
