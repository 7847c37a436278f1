"""The recording format: what ``viscover record`` (and ``viscover launch``) write into a run
folder, shared by the writer (:mod:`agent.mission.recorder`) and the reader
(:mod:`agent.sim.replay`).

A run folder holds ``events.jsonl`` (one JSON object per line: ``time`` [s since the epoch],
``t`` [s since the recording started], ``source``, ``kind``, ``level``, ``text`` and the
kind's fields; the Structs of :mod:`agent.storage.events`) and ``recording.mcap`` (opens in
Foxglove). MCAP topics, log time = wall
time of reception [ns since the epoch]:

==========================  =======================  =========================================
topic                       schema                   content
==========================  =======================  =========================================
``/mission/info``           viscover.MissionInfo     once: scenario, agents, landmarks q, u
``/agents/<id>/state``      viscover.AgentState      every state received (JSON)
``/agents/<id>/pose``       viscover.Pose            every pose received: t [s], p [m], v (JSON)
``/mission/coverage``       viscover.Coverage        coverage (eq. 3.10), landmarks seen by owner
``/drones/<id>/pose``       foxglove.PoseInFrame     the agent's pose, camera along +x
``/drones/<id>/mocap``      foxglove.PoseInFrame     the ground station's motion capture
``/drones/<id>/tf``         foxglove.FrameTransform  ``world`` → ``drone/<id>`` (thinned as the
                                                     pose): the drone's position, level, heading
                                                     of its camera
``/drones/<id>/camera_tf``  foxglove.FrameTransform  ``drone/<id>`` → ``drone/<id>/camera``: the
                                                     camera's optical frame (+z optical axis,
                                                     +x image right, +y image down)
``/scene/drones``           foxglove.SceneUpdate     bodies, safety spheres, camera arrows and
                                                     frusta (depth d_opt), labels
``/scene/mission``          foxglove.SceneUpdate     the mission space (box edges)
``/landmarks``              foxglove.PointCloud      landmarks coloured by owner (fields x, y,
                                                     z, red, green, blue, alpha, id, owner)
``/events``                 foxglove.Log             the lines of ``events.jsonl``
==========================  =======================  =========================================

Frames: ``world`` (ENU, metres); per drone ``drone/<id>`` and ``drone/<id>/camera``
(:func:`agent.mission.scene.frame_transforms`). Live viewers that join late get the latest
``/mission/info``, ``/scene/mission``, ``/landmarks`` and ``/landmarks/captures`` at once
(:mod:`agent.mission.live`). Colours: agent i has matplotlib's ``C{i}``, as in
the report's plots; a landmark nobody owns is grey.
"""

from __future__ import annotations

from importlib import metadata
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from agent.config.digest import scenario_digest
from agent.config.scenario import Scenario
from agent.wire.peer import AgentState, Pose

Array = NDArray[np.float64]

MCAP_NAME: Final = "recording.mcap"
EVENTS_NAME: Final = "events.jsonl"
INFO_TOPIC: Final = "/mission/info"
COVERAGE_TOPIC: Final = "/mission/coverage"
DRONES_TOPIC: Final = "/scene/drones"
MISSION_TOPIC: Final = "/scene/mission"
LANDMARKS_TOPIC: Final = "/landmarks"
#: an inspection's landmarks coloured by capture state (agent.mission.capture_scene)
CAPTURES_TOPIC: Final = "/landmarks/captures"
EVENTS_TOPIC: Final = "/events"
WORLD: Final = "world"

#: matplotlib's tab10 cycle (C0..C9) as RGB in [0, 1]: agent i is drawn in row i % 10.
PALETTE: Final = np.array([
    [0.122, 0.467, 0.706], [1.000, 0.498, 0.055], [0.173, 0.627, 0.173],
    [0.839, 0.153, 0.157], [0.580, 0.404, 0.741], [0.549, 0.337, 0.294],
    [0.890, 0.467, 0.761], [0.498, 0.498, 0.498], [0.737, 0.741, 0.133],
    [0.090, 0.745, 0.812]])
#: colour of a landmark without owner (in flight or never claimed)
UNOWNED: Final = np.array([0.75, 0.75, 0.75])


def frame_topic(agent_id: str) -> str:
    """MCAP topic of the FrameTransform ``world`` → ``drone/<id>``."""
    return f"/drones/{agent_id}/tf"


def camera_frame_topic(agent_id: str) -> str:
    """MCAP topic of the FrameTransform ``drone/<id>`` → ``drone/<id>/camera``."""
    return f"/drones/{agent_id}/camera_tf"


def drone_frame(agent_id: str) -> str:
    """Frame id of a drone (level, heading of its camera)."""
    return f"drone/{agent_id}"


def camera_frame(agent_id: str) -> str:
    """Frame id of a drone's camera (optical: +z along the optical axis, +x right, +y down)."""
    return f"drone/{agent_id}/camera"


def state_topic(agent_id: str) -> str:
    """MCAP topic of an agent's states (JSON)."""
    return f"/agents/{agent_id}/state"


def track_topic(agent_id: str) -> str:
    """MCAP topic of an agent's poses (JSON)."""
    return f"/agents/{agent_id}/pose"


def pose_topic(agent_id: str) -> str:
    """MCAP topic of an agent's pose for Foxglove (PoseInFrame)."""
    return f"/drones/{agent_id}/pose"


def mocap_topic(agent_id: str) -> str:
    """MCAP topic of a drone's motion capture for Foxglove (PoseInFrame)."""
    return f"/drones/{agent_id}/mocap"


def _finite_or_none(a: Array) -> list[float | None]:
    """A vector as JSON numbers, infinite components as null."""
    return [float(x) if np.isfinite(x) else None for x in np.asarray(a, dtype=np.float64)]


def info_document(sc: Scenario, mission: str, started: float) -> dict[str, Any]:
    """The ``/mission/info`` payload: scenario (and its digest), agents, landmarks [m], space,
    initial state, ``started`` [s since the epoch], the recording software's version."""
    try:
        software = metadata.version("viscover")
    except metadata.PackageNotFoundError:
        software = "unknown"
    return {
        "scenario": sc.name, "source": sc.source, "mission": mission, "seed": int(sc.seed),
        "digest": scenario_digest(sc), "software": software,
        "planar": bool(sc.planar), "d_opt": float(sc.d_opt), "visibility": sc.visibility,
        "dt": float(sc.params.dt), "r_s": float(sc.params.r_s),
        "agents": [a.id for a in sc.agents],
        "landmark_ids": [int(x) for x in sc.landmark_ids],
        "q": np.asarray(sc.q, dtype=np.float64).tolist(),
        "u": np.asarray(sc.u, dtype=np.float64).tolist(),
        "space_lo": _finite_or_none(sc.space.lo), "space_hi": _finite_or_none(sc.space.hi),
        "initial_partition": {a.id: [int(sc.landmark_ids[j]) for j in a.landmarks.tolist()]
                              for a in sc.agents},
        "initial_poses": {a.id: {"p": np.asarray(a.p0, dtype=np.float64).tolist(),
                                 "v": np.asarray(a.v0, dtype=np.float64).tolist()}
                          for a in sc.agents},
        "started": started,
    }


def state_document(st: AgentState, owned: list[int], held: list[int]) -> dict[str, Any]:
    """A ``/agents/<id>/state`` payload: the state's fields, landmark sets as id lists, the
    battery's charge [%] and voltage [V] (null: not reported, or no battery)."""
    c, b = st.counters, st.battery
    return {
        "t": st.t, "incarnation": st.incarnation, "seq": st.seq, "phase": st.phase,
        "p": list(st.p), "v": list(st.v), "vision": st.vision, "owned": owned, "held": held,
        "ok": c.ok, "failed": c.failed, "busy": c.busy, "timeouts": c.timeouts,
        "rejected": c.rejected, "partners": st.partners, "pending": st.pending,
        "trades_with": st.trades_with, "complete": st.complete,
        "battery_pct": None if b is None else b.pct,
        "battery_v": None if b is None else b.voltage_v,
    }


def pose_document(pose: Pose) -> dict[str, Any]:
    """A ``/agents/<id>/pose`` payload: mission time t [s], p [m], unit direction v."""
    return {"t": pose.t, "seq": pose.seq, "p": list(pose.p), "v": list(pose.v)}


#: JSON schemas of the JSON topics (enough for Foxglove's plots to offer the fields).
SCHEMAS: Final[dict[str, dict[str, Any]]] = {
    "viscover.MissionInfo": {"type": "object", "properties": {
        "scenario": {"type": "string"}, "mission": {"type": "string"},
        "agents": {"type": "array", "items": {"type": "string"}},
        "landmark_ids": {"type": "array", "items": {"type": "integer"}}}},
    "viscover.AgentState": {"type": "object", "properties": {
        "t": {"type": "number"}, "phase": {"type": "string"}, "vision": {"type": "number"},
        "incarnation": {"type": "integer"}, "seq": {"type": "integer"},
        "p": {"type": "array", "items": {"type": "number"}},
        "v": {"type": "array", "items": {"type": "number"}},
        "owned": {"type": "array", "items": {"type": "integer"}},
        "held": {"type": "array", "items": {"type": "integer"}},
        "ok": {"type": "integer"}, "failed": {"type": "integer"},
        "timeouts": {"type": "integer"}, "rejected": {"type": "integer"},
        "complete": {"type": "boolean"}, "battery_pct": {"type": ["number", "null"]},
        "battery_v": {"type": ["number", "null"]}}},
    "viscover.Pose": {"type": "object", "properties": {
        "t": {"type": "number"}, "seq": {"type": "integer"},
        "p": {"type": "array", "items": {"type": "number"}},
        "v": {"type": "array", "items": {"type": "number"}}}},
    "viscover.Coverage": {"type": "object", "properties": {
        "coverage": {"type": "number"}, "seen": {"type": "integer"},
        "not_seen": {"type": "integer"}, "unowned": {"type": "integer"}}},
}


def owner_index(landmark_ids: NDArray[np.int64], owned: list[NDArray[np.int64]]
                ) -> NDArray[np.intp]:
    """Owner row of each landmark (agent i owns ids ``owned[i]``), -1 for none."""
    owner = np.full(landmark_ids.shape[0], -1, dtype=np.intp)
    order = np.argsort(landmark_ids, kind="stable")
    ids_sorted = landmark_ids[order]
    for i, ids in enumerate(owned):  # a loop over agents; the landmarks are vectorised
        pos = np.searchsorted(ids_sorted, ids)
        ok = (pos < ids_sorted.size) & (ids_sorted[np.minimum(pos, ids_sorted.size - 1)]
                                         == ids)
        owner[order[pos[ok]]] = i
    return owner


def seen_by_owner(q: Array, u: Array, owner: NDArray[np.intp], p: Array, v: Array
                  ) -> NDArray[np.bool_]:
    """Section 4.2's Q^V test of each landmark (q, u) for its owner's camera (p [m], v)."""
    mine = owner >= 0
    k = np.where(mine, owner, 0)
    d = q - p[k]
    facing = (np.einsum("ij,ij->i", d, v[k]) > 0.0) & (np.einsum("ij,ij->i", d, u) < 0.0)
    return np.asarray(facing & mine, dtype=np.bool_)


def landmark_colours(owner: NDArray[np.intp]) -> NDArray[np.uint8]:
    """RGBA bytes (m, 4) of each landmark: its owner's colour, grey without an owner."""
    rgb = np.where((owner >= 0)[:, None], PALETTE[np.maximum(owner, 0) % len(PALETTE)],
                   UNOWNED[None, :])
    out = np.empty((owner.shape[0], 4), dtype=np.uint8)
    out[:, :3] = np.round(rgb * 255.0).astype(np.uint8)
    out[:, 3] = 255
    return out
