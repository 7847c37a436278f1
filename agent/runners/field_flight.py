"""A flying agent's field clients (:mod:`agent.flight.field`) put to work: what to open from
the flight options and the scenario (the pose source, the fence with a geodetic origin), the
camera triggered at every capture of an inspection, and each image's record kept.

A drone whose battery will not last through its remaining work and the way home
(:class:`BatteryWatch`) hands every landmark it owns over to its peers by trades
(:class:`agent.runtime.moves.handover.HandOver`), says it leaves (departure ``battery``), flies
home and lands.

Every capture the inspection decides asks the camera for one image for those landmark ids
(:meth:`agent.flight.camera.CameraClient.capture`); each finished capture (the vehicle's
CAMERA_IMAGE_CAPTURED or ArduPilot's CAMERA_FEEDBACK, or why it failed after its retries) is
appended, one JSON object per line, to ``<state dir>/images.jsonl`` next to the journal,
flushed and fsynced, said on stderr when it failed, and stepped into the agent core
(:meth:`agent.runtime.shell.runtime.AgentRuntime.image_taken`): only a taken image's capture
is journaled (:class:`~agent.protocol.records.CaptureRec`) and published. A vehicle without
a camera advertised fails every capture at once ("no camera"): it captures nothing.
"""

from __future__ import annotations

import json
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

from agent.config.scenario import Scenario
from agent.flight.battery import hand_over_needed
from agent.flight.camera import CaptureRecord
from agent.flight.fence import FenceBreach, FencePlan, fence_plan
from agent.flight.field import FieldClients
from agent.flight.geodetic import Origin
from agent.runtime.core.events import Depart
from agent.runtime.shell.runtime import AgentRuntime

_log = logging.getLogger(f"viscover.{__name__}")

IMAGES_FILE = "images.jsonl"

Array = NDArray[np.float64]


def fence_of(sc: Scenario, origin: Origin | None, margin_m: float) -> FencePlan | None:
    """The fence to upload: the mission space less ``margin_m`` [m] as the inclusion polygon
    and the landmarks' bounding box as the exclusion, placed at the geodetic ``origin``;
    None without an origin (a mocap room has no geodetic frame to put a fence in)."""
    if origin is None:
        return None
    return fence_plan(sc.space.lo, sc.space.hi, origin, margin_m,
                      structure=(sc.q.min(axis=0), sc.q.max(axis=0)))


def breach_line(agent_id: str) -> Callable[[FenceBreach], None]:
    """A callback saying a fence breach on stderr (the autopilot's own fence action flies)."""
    def said(b: FenceBreach) -> None:
        print(f"viscover: warning: {agent_id}: fence breach: {b}", file=sys.stderr, flush=True)
    return said


class ImageLog:
    """The camera's finished captures appended to ``<state_dir>/images.jsonl`` (fsynced)."""

    def __init__(self, agent_id: str, state_dir: Path, field: FieldClients) -> None:
        self.id, self.field = agent_id, field
        self.path = state_dir / IMAGES_FILE
        self._file: IO[str] | None = None
        self.images = self.failed = 0

    def drain(self) -> list[CaptureRecord]:
        """Append what the camera finished since the last call; returns it."""
        cam = self.field.camera
        if cam is None:
            return []
        recs = cam.drain()
        if not recs:
            return recs
        if self._file is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = self.path.open("a", encoding="utf-8")
        for r in recs:  # a loop over finished images (a few per second at most)
            row = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                   for k, v in r.to_dict().items()}
            self._file.write(json.dumps({"agent": self.id, **row}) + "\n")
            if r.status == "captured":
                self.images += 1
            else:
                self.failed += 1
                print(f"viscover: warning: {self.id}: image for landmarks "
                      f"{list(r.landmark_ids)} not taken: {r.reason}", file=sys.stderr)
        self._file.flush()
        os.fsync(self._file.fileno())
        return recs

    def close(self) -> None:
        """Append the last records and close the file."""
        self.drain()
        if self._file is not None:
            self._file.close()
            self._file = None


class BatteryWatch:
    """When the battery will not bring this drone through its remaining work and home:
    :func:`agent.flight.battery.hand_over_needed` over the inspection's remaining tour and the
    way home at ṗ_lim (a coverage mission: the way home only)."""

    def __init__(self, rt: AgentRuntime, field: FieldClients, home: Array, p_lim: float,
                 capacity_mah: float | None) -> None:
        self.rt, self.field, self.home = rt, field, home
        self.p_lim, self.capacity_mah = p_lim, capacity_mah

    def needed_s(self) -> float:
        """Flight time [s] the remaining work and the way home take at ṗ_lim."""
        p, _v, _ = self.rt.pose.current()
        work = self.rt.standing().tour_m or 0.0
        return (work + float(np.linalg.norm(np.asarray(p) - self.home))) / self.p_lim

    def due(self) -> bool:
        """Whether to hand the work over now."""
        state = self.field.battery.state
        return hand_over_needed(state, self.needed_s(), capacity_mah=self.capacity_mah)


class BatteryLeave:
    """Leaving for the battery, tick by tick: idle while :class:`BatteryWatch` says the
    charge lasts; then a :class:`~agent.runtime.core.events.Depart` (``battery``, with a hand-over
    of up to ``timeout_s`` [s mission]) is stepped into the core, which hands the work over
    (:mod:`agent.runtime.core.departing`; an inspection drone stops taking work and gives up what it
    still owns uncaptured), says it leaves, and ends with a Departed effect: :meth:`tick` then
    answers True: leave the loop, fly home, land."""

    def __init__(self, rt: AgentRuntime, watch: BatteryWatch, timeout_s: float = 60.0) -> None:
        self.rt, self.watch, self.timeout_s = rt, watch, timeout_s
        self.asked = False  #: the Depart was stepped in

    @property
    def left(self) -> bool:
        """Whether the drone has left the mission for its battery."""
        return self.rt.departed is not None

    def tick(self, now: float) -> bool:
        """One tick of the leave; True when the agent is to leave the mission now."""
        rt = self.rt
        if rt.departed is not None:
            print(f"viscover: agent {rt.id}: left the mission: {rt.departed.detail}",
                  file=sys.stderr, flush=True)
            return True
        if self.asked or not self.watch.due():
            return False
        self.asked = True
        owned = len(rt.standing().owned)
        print(f"viscover: warning: {rt.id}: battery {self.watch.field.battery.state.summary()}"
              f" will not last {self.watch.needed_s():.0f} s of work and the way home: "
              f"handing {owned} landmarks over, then home", file=sys.stderr)
        rt.step(Depart(now, "battery", hand_over_s=self.timeout_s))
        return False
