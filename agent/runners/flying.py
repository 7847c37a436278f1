"""A flying agent: the agent runtime with a quadcopter as its pose source (thesis chapter 6),
as a sequence of phases: connect, take off, mission, home, land.

(Over 400 lines, not split: the phases share one vehicle, one runtime and one clock, and
each phase's failure decides how the next ends; the two entry points, the agent and
``viscover fly``, run the same first phases.)

It runs the same :class:`~agent.runtime.shell.runtime.AgentRuntime` as a kinematic agent (same trade
protocol, same journal, same loop: :func:`agent.runners.process.agent_loop`) with three
differences:

* **clock**: the ground station's shared simulation clock (``viscover/<m>/clock``, followed
  by :class:`~agent.net.clocksync.RemoteClock`), never the process's own wall clock, so mocap
  timestamps and the runtime agree and a simulated mission may run faster than real time;
* **pose**: :class:`~agent.flight.vehicle_pose.MavlinkPoseSource`: position and yaw from
  motion capture, the camera latitude simulated (section 6.1), the planner's velocities
  flown by :class:`~agent.flight.controllers.FlightController` through a
  :class:`~agent.flight.mavlink_driver.MavlinkDriver` (SET_ATTITUDE_TARGET over MAVLink);
* **convergence**: a flown vehicle circles its optimum by a few centimetres, so besides
  section 4.4's test the agent also converges once its measured pose has settled
  (:class:`~agent.runners.settling.Settling`).

Phases: wait for the clock; connect (the vehicle's HEARTBEAT) and check the autopilot
(:mod:`agent.flight.autopilot_check`: its parameters read over the parameter protocol, a
one-line refusal, exit 2, when it would ignore our mocap or set-points; the hover thrust seeded
from MOT_THST_HOVER / MPC_THR_HOVER); engage the vehicle (mode, arm) and fly from the ground to
the initial pose (figure 6.2; after a restart, to the last journaled pose); run the planner /
trade loop, holding position and yaw whenever the agent is not optimising; on completion fly
home (:func:`agent.runners.going_home.fly_home`) and land. SIGINT/SIGTERM, ``timeout_s`` or a
flight failure stop the runtime and land the drone where it is. When the vehicle leaves our
control (link lost, a pilot's or failsafe's mode change, disarmed, battery critical: the
driver's monitor) the agent stops commanding at once, says why, stops its runtime (its
liveliness token vanishes, so the peers drop it from their partner lists) and exits 1 without
commanding a landing.

Each phase is one line on stderr, ``viscover-flight-agent A: <phase>`` (connected, pre-flight
ok, armed, took off, on station, complete, landing, landed, or ``left the mission: <why>``).
On stdout: ``viscover-flight-agent hovering id=A t=T`` once at the initial pose and (with
``exit_on_complete``) one JSON line once the mission is complete. Exit statuses: 0 done and
landed; 1 flight failure or the vehicle left our control; 2 a user mistake (including a
refused pre-flight check); 3 not complete within ``timeout_s``.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from agent.clock import Clock
from agent.config.flight import FlightSection, drone_ports, load_flight
from agent.config.scenario import AgentSpec, Scenario
from agent.core.orientation import angles_from_direction
from agent.errors import EXIT_FAILURE, EXIT_OK, UsageError
from agent.flight.attitude import ThrustModel
from agent.flight.autopilot_check import AutopilotReport, check_autopilot, seed_hover_thrust
from agent.flight.controllers import FlightConfig, FlightController
from agent.flight.driver_types import DriverConfig, FlightError
from agent.flight.field import FieldClients, FieldOptions, PoseSourceName
from agent.flight.geodetic import Origin
from agent.flight.mavlink_driver import MavlinkDriver, land_on_signals
from agent.flight.vehicle_pose import MavlinkPoseSource, MocapNeighbours, ZenohMocapFeed
from agent.net.clocksync import RemoteClock
from agent.net.transport import Transport
from agent.runners.departure import announce_departure
from agent.runners.field_flight import (
    BatteryLeave,
    BatteryWatch,
    ImageLog,
    breach_line,
    fence_of,
)
from agent.runners.going_home import PublishedNeighbours, fly_home, launch_point
from agent.runners.orders import Orders
from agent.runners.process import (
    AgentOptions,
    agent_loop,
    ensure_id_free,
    make_fault_injector,
    open_journal,
    open_transport,
    stop_on_signals,
)
from agent.runners.recovery import refuse_forgotten_id
from agent.runners.settling import Settling
from agent.runtime.shell.runtime import AgentRuntime
from agent.storage.journal import default_state_dir
from agent.wire import keys
from agent.wire.departure import departure_reason_of_release

_log = logging.getLogger("viscover.flight_agent")

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FlightOptions:
    """The flight side of a flying agent (durations in simulation seconds unless stated)."""

    flight_file: str | None = None  #: flight settings (default ``<scenario>.flight.toml``)
    scenario_path: str = ""  #: the scenario file (to find its sibling flight settings)
    mavlink: str | None = None  #: pymavlink connection (default: this drone's sim port)
    setpoint_rate_hz: float = 50.0
    mocap_stale_s: float = 0.2
    takeoff_timeout_s: float = 60.0
    settle_window_s: float = 2.0
    settle_radius_m: float = 0.1
    settle_angle_rad: float = 0.05
    landing: Literal["home", "here"] = "home"
    home_timeout_s: float = 120.0
    clock_timeout_s: float = 10.0  #: wall seconds to wait for the ground station's clock
    link_timeout_s: float = 3.0  #: no vehicle HEARTBEAT this long: link lost, leave
    battery_critical_pct: float = 15.0  #: battery remaining at or below this [%]: leave
    #: the pack's capacity [mAh] for the endurance estimate of the hand-over (None: the
    #: autopilot's own estimate, else a remaining charge of 30 % hands the work over)
    battery_capacity_mah: float | None = None
    hand_over: bool = True  #: hand the work over when the battery will not last
    #: where the pose comes from: motion capture over Zenoh, or the autopilot's own estimate
    pose: PoseSourceName = "mocap"
    #: the mission's geodetic origin shared by every drone (pose "autopilot"); with it the
    #: mission space less ``fence_margin_m`` [m] is uploaded as the autopilot's fence
    origin: Origin | None = None
    fence_margin_m: float = 1.0


def vehicle_connection(agent_id: str, fopts: FlightOptions, flight: FlightSection,
                       drone_ids: list[str]) -> str:
    """``--mavlink``, or ``udpout:<host>:<port>`` of this drone from the flight settings."""
    if fopts.mavlink:
        return fopts.mavlink
    port = drone_ports(flight, drone_ids)[agent_id]
    if not port:
        raise UsageError("--mavlink is required: the flight settings give no fixed port for "
                         f"drone {agent_id}")
    return f"udpout:{flight.host}:{port}"


def follow_clock(tp: Transport, mission: str, timeout_s: float) -> RemoteClock:
    """The ground station's clock, once its first message arrived (else a usage error)."""
    remote = RemoteClock(tp, mission)
    if not remote.wait_synced(timeout_s):
        remote.close()
        raise UsageError(f"no clock on {keys.clock_key(mission)} within {timeout_s:g} s: "
                         "is the ground station running?")
    return remote


def say(agent_id: str, phase: str) -> None:
    """One phase line on stderr: ``viscover-flight-agent A: <phase>``."""
    print(f"viscover-flight-agent {agent_id}: {phase}", file=sys.stderr, flush=True)


#: Driver phases worth a line (the others are said by the agent itself).
_DRIVER_PHASES = {"landing": "landing", "landed": "landed"}


def phase_announcer(agent_id: str, driver: MavlinkDriver) -> Callable[[str], None]:
    """The driver's ``on_phase``: one line per phase worth saying, the mocap failsafe's with
    its reason (``mocap lost (newest pose 0.310 s old, limit 0.200 s): level hover at hover
    thrust``) and its end (``mocap back after 0.40 s: resuming``, s sim). The driver then
    keeps those out of its log, so each is said once."""
    last = ["idle"]

    def on_phase(phase: str) -> None:
        before, last[0] = last[0], phase
        if phase == "failsafe_hold":
            say(agent_id, f"mocap lost ({driver.failsafe_reason}): level hover at hover thrust")
        elif phase == "flying" and before == "failsafe_hold":
            say(agent_id, f"mocap back after {driver.failsafe_s:.2f} s: resuming")
        elif phase in _DRIVER_PHASES:
            say(agent_id, _DRIVER_PHASES[phase])

    return on_phase


@dataclass
class Vehicle:
    """A connected vehicle: its mocap feed, driver, the pose source the planner uses, and
    what its autopilot reported at connect."""

    feed: ZenohMocapFeed
    driver: MavlinkDriver
    source: MavlinkPoseSource
    report: AutopilotReport
    field: FieldClients | None = None  #: camera, gimbal, fence, battery, autopilot pose

    def close(self) -> None:
        """Close the field clients, stop streaming, release the link and the subscription."""
        if self.field is not None:
            self.field.close()
        self.driver.close()
        self.feed.close()


def connect_vehicle(tp: Transport, mission: str, agent_id: str, scenario: Scenario,
                    conn: str, autopilot: str, fopts: FlightOptions, clock: Clock,
                    faults: Any = None) -> Vehicle:
    """Phase 1: mocap feed, controller and MAVLink driver (not yet engaged); the vehicle's
    HEARTBEAT and parameters (pre-flight check; hover thrust seeded). Raises FlightError
    without a vehicle, UsageError when the pre-flight check refuses."""
    ctl = FlightController(FlightConfig(model=ThrustModel(), lo=scenario.space.lo,
                                        hi=scenario.space.hi))
    holder: list[MavlinkDriver] = []
    feed = ZenohMocapFeed(tp, mission, agent_id,
                          on_pose=lambda: holder[0].notify_pose() if holder else None)
    try:
        driver = MavlinkDriver(conn, feed, ctl,
                               DriverConfig(autopilot=autopilot, rate_hz=fopts.setpoint_rate_hz,
                                            mocap_stale_s=fopts.mocap_stale_s,
                                            heartbeat_timeout_s=fopts.link_timeout_s,
                                            battery_critical_pct=fopts.battery_critical_pct),
                               clock, faults=faults)
    except FlightError as e:
        feed.close()
        raise UsageError(str(e)) from None
    holder.append(driver)
    driver.on_phase = phase_announcer(agent_id, driver)
    driver.start()
    try:
        fence = fence_of(scenario, fopts.origin, fopts.fence_margin_m)
    except ValueError as e:
        driver.close()
        feed.close()
        raise UsageError(f"{agent_id}: {e}") from None
    try:
        driver.wait_heartbeat()
        report = check_autopilot(driver, ctl.model.hover_thrust, pose=fopts.pose,
                                 fence=fence is not None)
    except BaseException:
        driver.close()
        feed.close()
        raise
    say(agent_id, f"connected to {conn} ({report.autopilot} system {report.system})")
    if report.fatal:
        driver.close()
        feed.close()
        raise UsageError(f"{agent_id}: {report.refusal()}")
    seed_hover_thrust(driver, report)
    say(agent_id, f"pre-flight ok: {report.summary()}")
    try:
        field = FieldClients(driver, FieldOptions(pose=fopts.pose, origin=fopts.origin,
                                                  fence=fence), on_breach=breach_line(agent_id))
    except BaseException:
        driver.close()
        feed.close()
        raise
    provider = field.pose if field.pose is not None else feed
    source = MavlinkPoseSource(driver, provider, gimbal=field.gimbal, battery=field.battery)
    return Vehicle(feed, driver, source, report, field)


def start_pose(rt: AgentRuntime, spec: AgentSpec, scenario: Scenario) -> tuple[Array, Array]:
    """Where to take off to: the scenario's initial pose, or the last journaled one after a
    restart ([m; world ENU], unit camera direction)."""
    lp = rt.standing().last_pose
    if lp is not None and scenario.space.contains(np.asarray(lp.p, dtype=np.float64)):
        return np.asarray(lp.p, dtype=np.float64), np.asarray(lp.v, dtype=np.float64)
    return np.asarray(spec.p0, dtype=np.float64), np.asarray(spec.v0, dtype=np.float64)


def take_off(vehicle: Vehicle, p0: Array, v0: Array, timeout_s: float, agent_id: str) -> bool:
    """Phase 2: engage (mode, arm) and fly to the pose (p0 [m; world ENU], camera direction
    v0), saying armed, took off (10 cm above the launch point) and on station; False if not
    reached within ``timeout_s`` [s sim] or the vehicle left our control. Raises
    FlightError."""
    lat0, yaw0 = angles_from_direction(v0)
    lim = vehicle.source.latitude.lat_max
    vehicle.source.latitude.theta = min(max(lat0, -lim), lim)
    driver = vehicle.driver
    start = vehicle.source.pose()  # mocap, or the autopilot's own estimate outdoors
    driver.engage()
    say(agent_id, "armed")
    z_launch = float(start.p[2]) if start is not None else 0.0
    watcher = threading.Thread(target=_say_took_off, args=(vehicle, z_launch, agent_id),
                               name="took-off", daemon=True)
    watcher.start()
    ok = vehicle.source.goto(p0, yaw0, tol=0.1, timeout_s=timeout_s)
    watcher.join(1.0)
    if ok:
        p = vehicle.source.current()[0]
        say(agent_id, f"on station at ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) m")
    return ok


def _say_took_off(vehicle: Vehicle, z_launch: float, agent_id: str) -> None:
    """Say 'took off' once the height (mocap, or the autopilot's) is 10 cm above ``z_launch``
    [m] (while flying)."""
    d = vehicle.driver
    while d.phase in ("flying", "failsafe_hold"):
        s = vehicle.source.pose()
        if s is not None and float(s.p[2]) > z_launch + 0.1:
            say(agent_id, "took off")
            return
        time.sleep(d.clock.wall(0.05))


def left_mission(agent_id: str, driver: MavlinkDriver, rt: AgentRuntime | None = None) -> bool:
    """If the vehicle left our control, say why (one line; on the mesh too once the runtime
    ``rt`` runs) and return True."""
    r = driver.released
    if r is None:
        return False
    say(agent_id, f"left the mission: {r.reason}")
    if rt is not None:
        announce_departure(rt, departure_reason_of_release(r.code), r.reason)
    return True


def _mission(rt: AgentRuntime, vehicle: Vehicle, clock: Clock, opts: AgentOptions,
             stop: threading.Event, t_takeoff: float, t_hover: float,
             orders: Orders | None = None, leave: BatteryLeave | None = None) -> int:
    """Phase 3: the runtime's loop at Δt of simulation time; holds position whenever the
    agent is not optimising; obeys the operator's ``orders`` first; hands its work over and
    leaves when ``leave`` says the battery will not last; ends with the exit status."""
    source, driver = vehicle.source, vehicle.driver
    images = None
    if vehicle.field is not None and vehicle.field.camera is not None:
        images = ImageLog(rt.id, opts.state_dir or default_state_dir(opts.mission, rt.id),
                          vehicle.field)
        rt.on_trigger = vehicle.field.camera.capture  # one image per capture, which counts
        rt.camera_confirms = True  # only once the camera says the image was taken
    rt.start()

    def each_tick() -> int | None:
        if images is not None:  # the camera's word on each image, into the core
            for r in images.drain():
                rt.image_taken(r.landmark_ids, r.status == "captured", r.reason)
        if leave is not None and leave.tick(clock.now()):
            return EXIT_OK  # work handed over: home and land
        if rt.phase != "optimising" and source.controller.mode != "hold":
            source.hold()  # figure 6.2: position and angle hold while trading
        if left_mission(rt.id, driver, rt):
            return EXIT_FAILURE
        if driver.phase in ("landing", "landed"):  # the stale-mocap failsafe landed it
            why = f"the vehicle is {driver.phase} (mocap lost?)"
            print(f"viscover: error: {rt.id}: {why}", file=sys.stderr)
            announce_departure(rt, "mocap_lost", why)
            return EXIT_FAILURE
        return None

    def report() -> dict[str, Any]:
        s = driver.stats
        return {"takeoff_at_s": t_takeoff, "hover_at_s": t_hover,
                "time_scale": clock.time_scale, "setpoints": s.sent,
                "setpoints_dropped": s.dropped, "setpoints_blocked": s.blocked,
                "failsafes": s.failsafes, "commands_rejected": source.rejected,
                "settled": getattr(rt.settle, "settled", None),
                "hover_thrust_estimate": source.controller.model.hover_thrust}

    try:
        return agent_loop(rt, clock, stop, exit_on_complete=opts.exit_on_complete,
                          timeout_s=opts.timeout_s, each_tick=each_tick, report=report,
                          orders=orders)
    finally:
        if images is not None:
            images.close()


#: The slowest landing descent of the autopilots' defaults [m/s] (ArduPilot LAND_SPEED 0.5,
#: PX4 MPC_LAND_SPEED 0.7) and the time to detect the touch-down and disarm [s].
LAND_SPEED_MPS, LAND_DETECT_S = 0.5, 20.0


def landing_timeout(sc: Scenario) -> float:
    """How long [s sim] to wait for a landing from as high as the mission space allows."""
    top = float(sc.space.hi[2]) if np.isfinite(sc.space.hi[2]) else 100.0
    return LAND_DETECT_S + max(top, 0.0) / LAND_SPEED_MPS


def battery_leave(rt: AgentRuntime, vehicle: Vehicle, home: Array, sc: Scenario,
                  fopts: FlightOptions) -> BatteryLeave | None:
    """The battery hand-over of this flight (None when off or without field clients)."""
    if not fopts.hand_over or vehicle.field is None:
        return None
    return BatteryLeave(rt, BatteryWatch(rt, vehicle.field, home, sc.params.p_lim,
                                         fopts.battery_capacity_mah))


def run_flying_agent(opts: AgentOptions, fopts: FlightOptions) -> int:
    """Run one flying agent through its phases (see the module docstring); returns the exit
    status. Raises :class:`~agent.errors.UsageError` on a user mistake."""
    if opts.rate_scale != 1.0:
        raise UsageError("--rate-scale: a flying agent follows the ground station's clock; "
                         "speed it up with `viscover groundstation --time-scale X`")
    sc = opts.scenario
    ids = [a.id for a in sc.agents]
    spec = next(a for a in sc.agents if a.id == opts.agent_id)
    flight = load_flight(fopts.scenario_path, fopts.flight_file)
    conn = vehicle_connection(opts.agent_id, fopts, flight, ids)
    faults = make_fault_injector(opts)
    journal = open_journal(opts)
    tp = remote = vehicle = neighbours = published = rt = orders = None
    try:
        tp = open_transport(opts.zenoh, faults, opts.agent_id)
        ensure_id_free(tp, opts.mission, opts.agent_id)  # before touching the vehicle
        refuse_forgotten_id(tp, opts.mission, opts.agent_id, journal)
        remote = follow_clock(tp, opts.mission, fopts.clock_timeout_s)
        clock: Clock = remote
        try:
            vehicle = connect_vehicle(tp, opts.mission, opts.agent_id, sc, conn,
                                      flight.autopilot, fopts, clock, faults)
        except FlightError as e:
            print(f"viscover: error: {opts.agent_id}: {e}", file=sys.stderr)
            return EXIT_FAILURE
        # The way home keeps R_s from the others: indoors by the ground station's mocap of
        # them, outdoors (no mocap) by the poses the agents publish; it says its own.
        published = PublishedNeighbours(tp, opts.mission, opts.agent_id)
        if fopts.pose == "mocap":
            neighbours = MocapNeighbours(tp, opts.mission, opts.agent_id)
        # The runtime first (journal replay, new incarnation), then the vehicle.
        settle = Settling(fopts.settle_window_s, fopts.settle_radius_m, fopts.settle_angle_rad)
        rt = AgentRuntime(opts.agent_id, sc, tp, journal, clock, pose=vehicle.source,
                          config=opts.runtime_config(clock.time_scale), settle=settle)
        p0, v0 = start_pose(rt, spec, sc)
        orders = Orders(tp, opts.mission, opts.agent_id)  # acknowledged from here on
        code = EXIT_OK  # SIGINT/SIGTERM before the loop: landed, exit 0
        with land_on_signals(vehicle.driver, landing_timeout(sc)):
            try:
                home = launch_point(vehicle.source.pose(), spec.p0)
                t_takeoff = clock.now()
                if not take_off(vehicle, p0, v0, fopts.takeoff_timeout_s, opts.agent_id):
                    if left_mission(opts.agent_id, vehicle.driver):
                        return EXIT_FAILURE
                    print(f"viscover: error: {opts.agent_id}: initial pose not reached within "
                          f"{fopts.takeoff_timeout_s:g} s", file=sys.stderr)
                    return EXIT_FAILURE
            except FlightError as e:
                print(f"viscover: error: {opts.agent_id}: {e}", file=sys.stderr)
                return EXIT_FAILURE
            t_hover = clock.now()
            print(f"viscover-flight-agent hovering id={opts.agent_id} t={t_hover:.2f}",
                  flush=True)
            stop = threading.Event()
            leave = battery_leave(rt, vehicle, home, sc, fopts)
            with stop_on_signals(stop):  # within the loop: a clean stop, then land
                try:
                    code = _mission(rt, vehicle, clock, opts, stop, t_takeoff, t_hover, orders,
                                    leave)
                finally:
                    rt.stop()  # liveliness token gone: the peers drop this agent
            if code == EXIT_OK and rt.complete:
                say(opts.agent_id, "complete")
            # An operator's land is an orderly end (home, then land); stop lands right here.
            ordered = orders.received.command if orders.received is not None else None
            if ordered == "stop":
                say(opts.agent_id, "emergency stop: landing where it is")
            go_home = code == EXIT_OK and fopts.landing == "home" and ordered != "stop" and (
                rt.complete or ordered == "land" or (leave is not None and leave.left))
            published.seq = rt.standing().published  # above every pose it published
            if go_home and not fly_home(vehicle.source, neighbours or published, home, sc, clock,
                                        fopts.home_timeout_s, say=published.say):
                if left_mission(opts.agent_id, vehicle.driver):
                    return EXIT_FAILURE
                print(f"viscover: warning: {opts.agent_id}: not home within "
                      f"{fopts.home_timeout_s:g} s; landing where it is", file=sys.stderr)
        if code == EXIT_OK and vehicle.driver.phase != "landed":
            print(f"viscover: error: {opts.agent_id}: landing not confirmed", file=sys.stderr)
            return EXIT_FAILURE
        return code
    finally:
        if orders is not None:
            orders.close()
        if rt is not None:
            rt.stop()
        if vehicle is not None:
            vehicle.close()
        if neighbours is not None:
            neighbours.close()
        if published is not None:
            published.close()
        if remote is not None:
            remote.close()
        if tp is not None:
            tp.close()
        journal.close()
        if faults is not None:
            faults.close()


def run_hover(agent_id: str, scenario: Scenario, mission: str, zenoh_cfg: Any,
              fopts: FlightOptions, duration_s: float | None) -> int:
    """``viscover fly``: take off to the agent's initial pose, hold it for ``duration_s``
    [s sim] or until SIGINT/SIGTERM, land. No planner, no trading: a first flight test of a
    drone, its mocap and its autopilot. Prints ``viscover-fly hovering id=A`` on station."""
    spec = next(a for a in scenario.agents if a.id == agent_id)
    flight = load_flight(fopts.scenario_path, fopts.flight_file)
    conn = vehicle_connection(agent_id, fopts, flight, [a.id for a in scenario.agents])
    tp = open_transport(zenoh_cfg, None, f"fly-{agent_id}")
    remote = vehicle = None
    try:
        remote = follow_clock(tp, mission, fopts.clock_timeout_s)
        try:
            vehicle = connect_vehicle(tp, mission, agent_id, scenario, conn, flight.autopilot,
                                      fopts, remote)
            with land_on_signals(vehicle.driver):
                if not take_off(vehicle, spec.p0, spec.v0, fopts.takeoff_timeout_s, agent_id):
                    if left_mission(agent_id, vehicle.driver):
                        return EXIT_FAILURE
                    print(f"viscover: error: initial pose not reached within "
                          f"{fopts.takeoff_timeout_s:g} s", file=sys.stderr)
                    return EXIT_FAILURE
                print(f"viscover-fly hovering id={agent_id}", flush=True)
                t_end = np.inf if duration_s is None else remote.now() + duration_s
                while remote.now() < t_end:
                    if left_mission(agent_id, vehicle.driver):
                        return EXIT_FAILURE
                    time.sleep(remote.wall(0.1))
        except FlightError as e:
            print(f"viscover: error: {e}", file=sys.stderr)
            return EXIT_FAILURE
        if vehicle.driver.phase != "landed":
            print("viscover: error: landing not confirmed", file=sys.stderr)
            return EXIT_FAILURE
        return EXIT_OK
    finally:
        if vehicle is not None:
            vehicle.close()
        if remote is not None:
            remote.close()
        tp.close()


__all__ = ["FlightOptions", "fly_home", "run_flying_agent", "run_hover"]
