"""Flight settings of a mission, kept out of the scenario file (whose schema refuses unknown
fields): ``<scenario>.flight.toml`` next to the scenario, or any file given with ``--flight``.
Every key is optional.

.. code-block:: toml

    [flight]
    autopilot = "ardupilot"    # a registered flavour: "ardupilot" (GUIDED_NOGPS), "px4" (OFFBOARD)
    host = "127.0.0.1"         # where the simulated vehicles listen
    base_port = 14560          # drone i (scenario order) listens on base_port + i
    rate = 100.0               # mocap publish rate [Hz, simulation time]
    stale_s = 0.1              # a rigid body unseen this long is reported stale [s]
    landmarks_period_s = 1.0   # how often the landmark set is re-published [s]
    seed = 0                   # mocap noise seed

    [flight.vehicle]           # simulated vehicles (groundstation.vehicle.params.VehicleParams)
    mass = 1.5                 # [kg]
    hover_thrust = 0.5         # normalised thrust balancing m g (MOT_THST_HOVER, MPC_THR_HOVER)
    drag = 0.25                # [N s/m], on the air-relative velocity
    tau_att = 0.08             # attitude time constant [s]
    tau_thrust = 0.03          # motor lag (thrust time constant) [s]
    setpoint_timeout = 0.5     # GUID_TIMEOUT / COM_OF_LOSS_T [s]; omit = the autopilot's default
    wind = [0.0, 0.0, 0.0]     # steady wind [m/s; world NED]
    gust_std = 0.0             # gusts: standard deviation [m/s] ...
    gust_tau = 2.0             # ... and correlation time [s] (seeded)
    mocap_noise_pos = 0.0      # [m], Gaussian
    mocap_noise_att = 0.0      # [rad], Gaussian
    mocap_latency = 0.0        # [s]
    mocap_dropout = 0.0        # probability that a mocap sample is lost
    mass_step_after = 20.0     # a payload: mass × mass_step_factor this long after arming [s]
    mass_step_factor = 1.3     # (omit mass_step_after = never)
    gcs = "udp:127.0.0.1:14550"   # stream telemetry there unasked (SITL --out); omit = none
    params = { VISO_TYPE = 1 }    # autopilot parameters that differ from the defaults

    [flight.mocap]             # real motion capture (--source motioncapture)
    type = "qualisys"          # mock | vicon | optitrack | qualisys | vrpn
    host = "192.168.1.10"
    bodies = { cf1 = "A", cf2 = "B", cf3 = "C" }   # rigid-body name -> drone id
    mock_bodies = "cf1(0,0,1,1,0,0,0)"   # mock backend: name(x,y,z,qw,qx,qy,qz);...

    [flight.drones.A]          # per-drone overrides
    port = 14570
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import msgspec

from agent.config.scenario import ScenarioError
from agent.wire.mavlink import flavour


class VehicleSection(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[flight.vehicle]``: the simulated vehicle. The one place of these defaults:
    :class:`groundstation.vehicle.params.VehicleParams` extends this struct.

    Units: mass [kg], hover_thrust normalised (0..1), drag [N s/m], time constants [s],
    speeds [m/s], rates [Hz], wind [m/s; world NED], noise [m] / [rad], latency [s],
    mocap_dropout a probability, battery capacity [mAh] and cells (LiPo, in series),
    ``mass_step_after`` [s sim after the vehicle first armed] when its mass is multiplied by
    ``mass_step_factor`` (a payload picked up: a harder rehearsal for the hover estimate).
    ``setpoint_timeout`` None keeps the autopilot's own default (GUID_TIMEOUT 3 s,
    COM_OF_LOSS_T 1 s); ``gcs`` is a SITL ``--out`` address (``udp:host:port``);
    ``params`` overrides autopilot parameters by name (a wrongly configured autopilot).
    """

    mass: float = 1.5
    hover_thrust: float = 0.5
    drag: float = 0.25
    tau_att: float = 0.08
    tau_thrust: float = 0.03
    setpoint_timeout: float | None = 0.5
    land_speed: float = 0.5
    pilot_speed: float = 2.5
    telemetry_rate: float = 30.0
    wind: list[float] = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    gust_std: float = 0.0
    gust_tau: float = 2.0
    sensor_noise_pos: float = 0.0
    sensor_noise_att: float = 0.0
    mocap_noise_pos: float = 0.0
    mocap_noise_att: float = 0.0
    mocap_latency: float = 0.0
    mocap_dropout: float = 0.0
    battery_mah: float = 5000.0
    battery_cells: int = 4
    mass_step_after: float | None = None
    mass_step_factor: float = 1.3
    gcs: str | None = None
    params: dict[str, float] = msgspec.field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (self.mass > 0 and 0 < self.hover_thrust < 1 and self.tau_att > 0
                and self.tau_thrust > 0):
            raise ValueError("mass > 0, 0 < hover_thrust < 1, tau_att > 0 and tau_thrust > 0 "
                             "are required")
        if self.setpoint_timeout is not None and not self.setpoint_timeout > 0:
            raise ValueError("setpoint_timeout must be > 0 (or omitted)")
        if len(self.wind) != 3 or not (self.gust_std >= 0 and self.gust_tau > 0):
            raise ValueError("wind is [north, east, down] in m/s; gust_std >= 0, gust_tau > 0")
        if not 0.0 <= self.mocap_dropout < 1.0:
            raise ValueError("mocap_dropout is a probability in [0, 1)")
        if not (self.telemetry_rate > 0 and self.battery_mah > 0 and self.battery_cells > 0):
            raise ValueError("telemetry_rate, battery_mah and battery_cells must be > 0")
        if self.mass_step_after is not None and not (self.mass_step_after >= 0
                                                     and self.mass_step_factor > 0):
            raise ValueError("mass_step_after must be >= 0 [s] and mass_step_factor > 0")
        if self.gcs is not None and not self.gcs.startswith("udp:"):
            raise ValueError(f"gcs must be 'udp:host:port', got {self.gcs!r}")


class MocapSection(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[flight.mocap]``: the motion-capture system and the rigid-body → drone map."""

    type: str = "mock"
    host: str | None = None
    bodies: dict[str, str] = msgspec.field(default_factory=dict)
    mock_bodies: str | None = None


class DroneSection(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[flight.drones.<id>]``: per-drone UDP port of its simulated vehicle."""

    port: int | None = None


class FlightSection(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[flight]``."""

    autopilot: str = "ardupilot"
    host: str = "127.0.0.1"
    base_port: int = 14560
    rate: float = 100.0
    stale_s: float = 0.1
    landmarks_period_s: float = 1.0
    seed: int = 0
    vehicle: VehicleSection = msgspec.field(default_factory=VehicleSection)
    mocap: MocapSection = msgspec.field(default_factory=MocapSection)
    drones: dict[str, DroneSection] = msgspec.field(default_factory=dict)


class _FlightFile(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    flight: FlightSection = msgspec.field(default_factory=FlightSection)


def flight_path_for(scenario_path: str | Path) -> Path:
    """The sibling flight file of a scenario: ``x.toml`` → ``x.flight.toml``."""
    p = Path(scenario_path)
    return p.with_name(p.stem + ".flight.toml")


def parse_flight(text: str, source: str) -> FlightSection:
    """Parse flight settings; ScenarioError with ``source: field: problem`` on any mistake."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(f"{source}: not valid TOML: {e}") from None
    try:
        sec = msgspec.convert(raw, _FlightFile).flight
    except msgspec.ValidationError as e:
        raise ScenarioError(f"{source}: {e}") from None
    try:
        flavour(sec.autopilot)
    except ValueError as e:
        raise ScenarioError(f"{source}: flight.autopilot: {e}") from None
    if not sec.rate > 0 or not sec.stale_s > 0:
        raise ScenarioError(f"{source}: flight.rate and flight.stale_s must be > 0")
    if not 0 <= sec.base_port <= 65535:
        raise ScenarioError(f"{source}: flight.base_port: must be a UDP port (0-65535)")
    return sec


def load_flight(scenario_path: str | Path, flight_path: str | Path | None = None
                ) -> FlightSection:
    """``flight_path`` if given (must exist), else the scenario's sibling ``.flight.toml`` if
    it exists, else the defaults."""
    p = Path(flight_path) if flight_path is not None else flight_path_for(scenario_path)
    if not p.exists():
        if flight_path is not None:
            raise ScenarioError(f"{p}: no such flight settings file; check the path")
        return FlightSection()
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ScenarioError(f"{p}: cannot read: {e}") from None
    return parse_flight(text, str(p))


def drone_ports(sec: FlightSection, drone_ids: list[str]) -> dict[str, int]:
    """UDP port of each drone's simulated vehicle (per-drone override or base_port + index)."""
    unknown = sorted(set(sec.drones) - set(drone_ids))
    if unknown:
        raise ScenarioError(f"flight.drones: {', '.join(unknown)} not in the scenario's agents")
    out = {}
    for i, d in enumerate(drone_ids):
        port = sec.drones.get(d, DroneSection()).port
        out[d] = port if port is not None else (sec.base_port + i if sec.base_port else 0)
    return out
