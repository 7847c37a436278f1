"""The MAVLink parameter protocol over a :class:`~agent.flight.link.VehicleLink`:
PARAM_REQUEST_READ by name, PARAM_SET, and PARAM_VALUE decoded by its param_type (PX4 sends
integers byte-wise, ArduPilot as floats: :func:`agent.flight.driver_types.
decode_param_value`, chosen by the vehicle's flavour). PARAM_SET matches by name and the
autopilot keeps its own type for the value, so a write is confirmed by the PARAM_VALUE
that comes back. Times in simulation seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from agent.flight.driver_types import FlightError, decode_param_value
from agent.flight.link import VehicleLink
from agent.wire.mavlink import mavlink


class ParamClient:
    """Reads and writes the vehicle's parameters; values land in ``link.vehicle.params``."""

    def __init__(self, link: VehicleLink) -> None:
        self.link = link
        self._unsub = link.subscribe("PARAM_VALUE", self._on_value)

    def close(self) -> None:
        """Stop listening."""
        self._unsub()

    def _on_value(self, msg: Any) -> None:
        name = str(msg.param_id)
        value = decode_param_value(float(msg.param_value), int(msg.param_type),
                                   self.link.flavour.bytewise_params)
        with self.link.cond:
            self.link.vehicle.params[name] = value
            self.link.vehicle.param_types[name] = int(msg.param_type)

    def _forget(self, names: list[str]) -> None:
        with self.link.cond:
            for n in names:
                self.link.vehicle.params.pop(n, None)

    def _request(self, name: str) -> None:
        link = self.link
        link.send(lambda mav: mav.param_request_read_send(
            link.target_system, link.cfg.target_component, name.encode(), -1))

    def _write(self, name: str, value: float) -> None:
        link = self.link
        link.send(lambda mav: mav.param_set_send(
            link.target_system, link.cfg.target_component, name.encode(), value,
            mavlink.MAV_PARAM_TYPE_REAL32))

    def get(self, name: str) -> float:
        """Read one parameter, retried until its PARAM_VALUE comes back (FlightError)."""
        return self._exchange(name, None)

    def set(self, name: str, value: float) -> float:
        """Write one parameter; returns the value the vehicle confirms (FlightError)."""
        return self._exchange(name, value)

    def _exchange(self, name: str, value: float | None) -> float:
        link = self.link
        for _ in range(link.cfg.retries):
            self._forget([name])
            if value is None:
                self._request(name)
            else:
                self._write(name, float(value))
            if link.wait(lambda: name in link.vehicle.params, link.cfg.ack_timeout_s):
                return link.vehicle.params[name]
        raise FlightError(f"no PARAM_VALUE for {name} after {link.cfg.retries} tries")

    def read(self, names: list[str], rounds: int | None = None) -> dict[str, float]:
        """Read parameters by name (all at once; the missing ones asked again up to
        ``rounds`` times, ``ack_timeout_s`` each). Returns those that answered; an autopilot
        without a parameter never answers."""
        link = self.link
        self._forget(names)
        for _ in range(link.cfg.retries if rounds is None else rounds):
            missing = [n for n in names if n not in link.vehicle.params]
            if not missing:
                break
            for n in missing:
                self._request(n)
            link.wait(self._have(missing), link.cfg.ack_timeout_s)
        with link.cond:
            return {n: link.vehicle.params[n] for n in names if n in link.vehicle.params}

    def _have(self, names: list[str]) -> Callable[[], bool]:
        """A predicate: every parameter of ``names`` has arrived."""
        params = self.link.vehicle.params
        return lambda: all(n in params for n in names)

    def ensure_bits(self, name: str, bits: int) -> None:
        """Make integer parameter ``name`` include ``bits`` (read, OR, write, confirm)."""
        value = int(self.get(name)) | bits
        if int(self.set(name, value)) & bits != bits:
            raise FlightError(f"{name} was not set to include bits {bits}")
