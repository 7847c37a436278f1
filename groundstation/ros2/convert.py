"""A recorded run as a ROS 2 bag (``viscover ros2-bridge --from-recording RUN_DIR --bag DIR``):
the run folder's ``recording.mcap`` and ``events.jsonl`` (read by :mod:`agent.sim.replay`)
replayed in reception order through the same :class:`~groundstation.ros2.model.MissionRos`
as the live bridge, each message stamped with the time the recorder received its source.

What a recording holds gives: every agent pose (``<ns>/<drone>/pose``, ``/tf``, frusta), every
state (labels, landmark ownership: ``<ns>/landmarks``), the events (``<ns>/events``) and the
motion capture as the recorder thinned it (30 Hz): its attitude was kept as the body's x axis
only, so the body here heads and pitches along that axis, without roll. Not in a recording,
so not in the bag: ``<ns>/status`` (the live view) and an inspection's capture log and map
(states are recorded without their captured sets).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from agent.config.scenario import Scenario
from agent.storage.events import MissionEvent
from agent.storage.recording import owner_index
from groundstation.ros2 import frames
from groundstation.ros2 import typesupport as ts
from groundstation.ros2.bag import BagWriter
from groundstation.ros2.model import MissionRos
from groundstation.ros2.names import Names


class ConvertError(Exception):
    """The recording cannot be converted (one line, for the user)."""


def _ns(wall_s: float) -> int:
    return round(wall_s * 1e9)


#: one item of a recording's timeline: (wall time [s], order, kind, drone, document or event)
Item = tuple[float, int, str, str, dict[str, Any] | MissionEvent]


def timeline(rec: Any) -> list[Item]:
    """Every pose, state, mocap sample and event of a recording as (wall time [s], order,
    kind, drone, document or event), sorted by time (events before samples of the same
    instant)."""
    out: list[Item] = [(ev.time, 0, "event", "", ev) for ev in rec.events]
    for kind, streams in (("state", rec.states), ("pose", rec.poses), ("mocap", rec.mocap)):
        for aid, s in streams.items():
            out += [(w, 1, kind, aid, d) for w, d in zip(s.w, s.docs, strict=True)]
    out.sort(key=lambda x: (x[0], x[1]))
    return out


def read_run(run_dir: Path, sc: Scenario) -> Any:
    """The recording of ``run_dir`` (an :class:`agent.sim.replay.Recording`); a
    :class:`ConvertError` for a folder that is not a recording of ``sc``."""
    from agent.sim.replay import RecordingError, read_recording

    try:
        rec = read_recording(run_dir)
    except RecordingError as e:
        raise ConvertError(str(e)) from None
    if list(rec.info.get("landmark_ids", [])) != [int(i) for i in sc.landmark_ids]:
        raise ConvertError(f"{run_dir}: recorded with other landmarks than {sc.source} "
                           f"(scenario {rec.info.get('scenario')!r}): give its scenario")
    return rec


def convert(rec: Any, sc: Scenario, names: Names, bag: BagWriter) -> int:
    """Write recording ``rec`` (:func:`read_run`) of scenario ``sc`` into ``bag``; the number
    of messages written."""
    model = MissionRos(sc, names)
    lm_ids = np.asarray(sc.landmark_ids, dtype=np.int64)
    owned: dict[str, np.ndarray] = {}
    n = 0

    def write(outs: list[Any]) -> None:
        nonlocal n
        for o in outs:
            bag.write(o.topic, o.typename, ts.serialize(o.msg, o.typename), o.stamp_ns)
            n += 1

    for wall, _order, kind, aid, doc in timeline(rec):
        ns = _ns(wall)
        if isinstance(doc, MissionEvent):
            write([model.event(doc, ns)])
            continue
        if not model.known(aid) and not model.join(aid):
            continue
        if kind == "pose":
            write(model.pose(aid, doc["p"], doc["v"], ns))
        elif kind == "mocap":
            x, y, z, w = frames.camera_quat(doc["v"])
            write(model.mocap(aid, doc["p"], (w, x, y, z), ns))
        else:
            write(model.state(aid, str(doc.get("phase", "")), len(doc.get("owned", [])),
                              float(doc.get("vision", 0.0)), b"", ns))
            owned[aid] = np.asarray(doc.get("owned", []), dtype=np.int64)
            ids = list(owned)
            write(model.ownership(ids, owner_index(lm_ids, [owned[a] for a in ids]), ns))
    return n
