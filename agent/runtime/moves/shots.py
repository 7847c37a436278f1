"""An inspection drone's own captures as evidence: its claims (what it publishes of each image:
pose, time, landmarks; :mod:`agent.protocol.captures`) and the images it asked of a
confirming camera and waits for (a flown drone's, events ``Trigger`` then ``ImageTaken``):
their landmarks count as captured only at the camera's word. Its peers' claims are judged by
:mod:`agent.runtime.moves.claims`. Positions [m; world ENU], times [s] of its mission clock."""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from agent.core.inspection import camera_axes
from agent.protocol.captures import (
    CapturedSet,
    OwnClaims,
)
from agent.protocol.records import CaptureRec
from agent.runtime.core.events import Event, ImageTaken, Sample, Start
from agent.runtime.core.shared import vec3
from agent.runtime.moves.claims import ClaimJudge

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

_log = logging.getLogger(f"viscover.{__name__}")

#: An image the camera has not answered for this long [s mission] is taken as not taken.
SHOT_TIMEOUT_S = 30.0


#: An image asked of the camera: its landmarks' rows, time [s], position [m; world ENU], unit
#: optical axis, quality per landmark (eq. 3.1).
Shot = tuple[NDArray[np.intp], float, Array, Array, list[float]]


class Shots:
    """Images asked of a confirming camera and not answered yet, by their landmark ids (a
    landmark waiting for the camera is asked for in no other image)."""

    def __init__(self) -> None:
        self.pending: dict[tuple[int, ...], Shot] = {}

    def ask(self, ids: list[int], rows: NDArray[np.intp], t: float, p: Array, v: Array,
            quality: list[float]) -> None:
        """An image was asked for ``ids`` (``rows``) at ``t`` [s] from (p, v)."""
        self.pending[tuple(ids)] = (rows.copy(), t, p.copy(), v.copy(), quality)

    def answer(self, ids: tuple[int, ...]) -> Shot | None:
        """The shot the camera answered for ``ids`` (removed), None if unknown."""
        return self.pending.pop(tuple(int(i) for i in ids), None)

    def expire(self, now: float) -> list[NDArray[np.intp]]:
        """Drop the shots unanswered for :data:`SHOT_TIMEOUT_S` at ``now`` [s]; their rows."""
        old = [k for k, s in self.pending.items() if now - s[1] > SHOT_TIMEOUT_S]
        return [self.pending.pop(k)[0] for k in old]


class Captures:
    """One drone's captured set: its journaled captures and what its peers proved (merged by
    union), the images its camera has not confirmed yet, and its own claims.

    Args:
        ids: the mission's landmark ids (m,), in row order.
        captured: the capture records of its journal (claimed again after a restart).
        record: journals a capture record (persisted, fsynced, before anything names it).
        trigger: fires the camera for landmark ids (a Trigger effect).
    """

    def __init__(self, ids: NDArray[np.int64], captured: list[CaptureRec],
                 record: Callable[[CaptureRec], None],
                 trigger: Callable[[list[int]], None]) -> None:
        self.ids, self.record, self.trigger = ids, record, trigger
        self.captured = CapturedSet(i for r in captured for i in r.ids)
        self.cap = self.captured.mask(ids)  #: per row: captured (in place, shared)
        self.busy = np.zeros(ids.size, dtype=np.bool_)  #: per row: waiting for the camera
        self.shots = Shots()
        self.own = OwnClaims()  #: its own claims, its journal's first
        for r in captured:  # one per image
            self.own.add(r.t, np.asarray(r.p), np.asarray(r.v), r.ids)
        #: the camera confirms each image (a flown drone's, Start.camera): captures wait
        self.camera = False

    @property
    def done(self) -> Mask:
        """Per row (m,): captured, or waiting for the camera's word."""
        return self.cap | self.busy

    def merge(self, new: Mask) -> None:
        """Landmarks (m,) a peer proved captured."""
        if new.any():
            self.captured.merge(self.ids[new].tolist())
            self.cap |= new

    def took(self, rows: NDArray[np.intp], t: float, p: Array, v: Array,
             quality: list[float]) -> list[int]:
        """The camera images ``rows`` at ``t`` [s] from p [m; world ENU], unit v: without a
        confirming camera captured now (journaled, then the camera fires; their ids
        returned), with one asked for only (captured at :meth:`on_image`; none returned)."""
        new: list[int] = self.ids[rows].tolist()
        if self.camera:
            self.shots.ask(new, rows, t, p, v, quality)
            self.busy[rows] = True
            self.trigger(new)
            return []
        self._captured(new, rows, t, p, v, quality)
        self.trigger(new)  # the camera fires after the record is persisted
        return new

    def _captured(self, new: list[int], rows: NDArray[np.intp], t: float, p: Array, v: Array,
                  quality: list[float]) -> None:
        """Landmarks ``new`` (rows) captured: journaled first, then in the set and claimed."""
        self.record(CaptureRec(ids=new, t=t, p=vec3(p), v=vec3(v),
                               right=vec3(camera_axes(v[None, :])[0][0]), quality=quality))
        self.captured.merge(new)
        self.cap[rows] = True
        self.own.add(t, p, v, new)

    def on_image(self, ev: ImageTaken) -> None:
        """The camera's word on an image asked for: taken, its capture counts (journaled,
        then published with its claim); not taken, its landmarks are to capture again."""
        shot = self.shots.answer(ev.ids)
        if shot is None:
            _log.info("the camera answered for an image not asked for: %s", list(ev.ids)[:10])
            return
        rows, t, p, v, quality = shot
        self.busy[rows] = False
        if ev.ok:
            self._captured([int(i) for i in ev.ids], rows, t, p, v, quality)
        else:
            _log.warning("image for landmarks %s not taken (%s): not captured",
                         list(ev.ids)[:10], ev.reason[:120])

    def expire(self, now: float) -> None:
        """Images the camera never answered (:data:`SHOT_TIMEOUT_S`) at ``now`` [s]: not
        taken."""
        for rows in self.shots.expire(now):
            self.busy[rows] = False


def inspection_event(judge: ClaimJudge, caps: Captures, event: Event) -> None:
    """What an inspection drone takes from an event: whether its camera confirms images
    (Start), the peers' poses and mocap (evidence for their claims), the camera's word."""
    if isinstance(event, Start):
        caps.camera = event.camera
    elif isinstance(event, ImageTaken):
        caps.on_image(event)
    elif isinstance(event, Sample) and event.kind == "pose":
        judge.heard_pose(event.key, event.payload)
    elif isinstance(event, Sample) and event.kind == "mocap":
        judge.heard_mocap(event.key, event.payload, event.now)
