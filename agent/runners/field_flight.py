"""A flying agent's field clients (:mod:`agent.flight.field`) put to work: what to open from
the flight options and the scenario (the pose source, the fence with a geodetic origin), the
camera triggered at every capture of an inspection, and each image's record kept.

Every capture the inspection journals (:class:`~agent.protocol.records.CaptureRec`) asks the
camera for one image for those landmark ids (:meth:`agent.flight.camera.CameraClient.
capture`); each finished capture (the vehicle's CAMERA_IMAGE_CAPTURED or ArduPilot's
CAMERA_FEEDBACK, or why it failed after its retries) is appended, one JSON object per line,
to ``<state dir>/images.jsonl`` next to the journal, flushed and fsynced, and said on stderr
when it failed. A vehicle without a camera says so once; the inspection goes on (its
captures are then only the poses the journal holds).
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

from agent.config.scenario import Scenario
from agent.flight.camera import CaptureRecord
from agent.flight.fence import FenceBreach, FencePlan, fence_plan
from agent.flight.field import FieldClients
from agent.flight.geodetic import Origin

_log = logging.getLogger(f"viscover.{__name__}")

IMAGES_FILE = "images.jsonl"


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
