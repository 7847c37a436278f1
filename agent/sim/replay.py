"""A recording read back (:mod:`agent.storage.recording`): the JSON topics of ``recording.mcap`` as
arrays, and the :class:`~agent.sim.result.SimResult` that ``viscover simulate`` would have
produced, so that :func:`agent.sim.report.write_report` draws the same report.

Times. Each kinematic agent runs its own clock from its own start (a flown one follows the
ground station's), so mission times of different agents are not on one axis. The reader puts
them on one: the time scale s is the median over agents of the least-squares slope of mission
time against reception time, agent i's offset the median of t − s·w over its samples, and
τ = t − offset_i (τ = 0 at the first sample). The result is sampled every Δτ = max(dt,
span / 1500) on that axis and at its end, each agent holding its latest sample (its first
before it).

The vision of each agent is recomputed at every sample (eq. 3.8, own set at the held pose)
when the scenario's visibility is "facing"; the published values (one per state) otherwise.

A recording cut before any agent published (an interrupted flight) still has the ground
station's motion capture (``/drones/<id>/mocap``, PoseInFrame, thinned by the recorder): a
drone without states or poses is drawn from it, its mocap samples put on the common axis by
their reception time (τ = s·w − the axis origin; a drone's camera direction is its body x
axis, its camera latitude unknown). :attr:`Recording.missing` says what such a recording
cannot give.

Trades are read from the states' per-partner counters: the k-th trade of a pair happened when
the first of the two showed it (taken as the initiator); the landmarks it moved are those whose
owner changed between the partners around it, its gain the change of the coverage score.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
from mcap.reader import NonSeekingReader, make_reader
from numpy.typing import NDArray

from agent.core.vision import vision as vision_of
from agent.sim.result import SimResult, TradeEvent
from agent.storage.events import Event, EventDecoder, read_events
from agent.storage.recording import EVENTS_NAME, INFO_TOPIC, MCAP_NAME
from agent.wire.codec import RateLimitedLogger

_log = logging.getLogger(f"viscover.{__name__}")
Array = NDArray[np.float64]
#: Largest number of samples of the resampled result.
MAX_SAMPLES = 1500


class RecordingError(Exception):
    """A recording that cannot be read (one line, for the user)."""


@dataclass
class Stream:
    """One agent's JSON samples in reception order: wall time w [s], mission time t [s]."""

    w: list[float] = field(default_factory=list)
    docs: list[dict[str, Any]] = field(default_factory=list)

    @property
    def t(self) -> Array:
        """Mission times [s] of the samples."""
        return np.array([d["t"] for d in self.docs], dtype=np.float64)


@dataclass
class Recording:
    """What a run folder's recording holds."""

    info: dict[str, Any]
    states: dict[str, Stream]
    poses: dict[str, Stream]
    counts: dict[str, int]  #: messages per MCAP topic
    events: list[Event]  #: the lines of ``events.jsonl`` that decode
    complete_file: bool  #: the MCAP summary was written (the recorder closed it)
    #: mocap tracks: docs {t: reception wall time [s], p [m], v: body x axis}
    mocap: dict[str, Stream] = field(default_factory=dict)
    events_skipped: int = 0  #: lines of ``events.jsonl`` that do not decode (torn, foreign)

    @property
    def empty(self) -> bool:
        """Nothing of any drone: no state, no pose, no mocap sample."""
        return not any(s.docs for box in (self.states, self.poses, self.mocap)
                       for s in box.values())

    @property
    def missing(self) -> str | None:
        """What the report cannot show (one line), or None when agent states were recorded."""
        if self.states:
            return None
        what = "poses" if self.poses else "motion capture" if self.mocap else "nothing"
        return (f"interrupted before any agent state: no partition, no coverage "
                f"(trajectories from {what})")


def find_mcap(run_dir: Path) -> Path:
    """A run folder's newest recording (``recording-<n>.mcap`` of a resumed run, else
    ``recording.mcap``, else any ``*.mcap``)."""
    found = sorted(run_dir.glob("*.mcap"), key=lambda p: (p.stat().st_mtime, p.name))
    if not found:
        raise RecordingError(f"{run_dir}: no recording (no {MCAP_NAME} inside); record one "
                             "with viscover launch or viscover record --out DIR")
    return found[-1]


def _read_events(run_dir: Path) -> tuple[list[Event], int]:
    """The events of ``events.jsonl`` and how many lines did not decode (skipped, logged)."""
    dec = EventDecoder(log=RateLimitedLogger(_log))
    return read_events(run_dir / EVENTS_NAME, dec), dec.counter.total


def _varints(data: bytes) -> dict[int, Any]:
    """The fields of one protobuf message: number → double (wire type 1), bytes (2) or int
    (0); enough for foxglove's PoseInFrame / Pose / Vector3 / Quaternion."""
    out: dict[int, Any] = {}
    i = 0

    def varint() -> int:
        nonlocal i
        v = shift = 0
        while True:
            b = data[i]
            i += 1
            v |= (b & 0x7F) << shift
            shift += 7
            if not b & 0x80:
                return v

    while i < len(data):
        key = varint()
        number, wire = key >> 3, key & 7
        if wire == 0:
            out[number] = varint()
        elif wire == 1:
            out[number] = float(np.frombuffer(data, "<f8", 1, i)[0])
            i += 8
        elif wire == 2:
            n = varint()
            out[number] = data[i:i + n]
            i += n
        elif wire == 5:
            i += 4
        else:
            raise ValueError(f"protobuf wire type {wire}")
    return out


def mocap_doc(data: bytes, wall: float) -> dict[str, Any]:
    """A ``/drones/<id>/mocap`` PoseInFrame as {t: wall [s], p [m], v: the body x axis}."""
    pose = _varints(_varints(data).get(3, b""))
    pos, rot = _varints(pose.get(1, b"")), _varints(pose.get(2, b""))
    x, y, z, w = (float(rot.get(k, 0.0)) for k in (1, 2, 3, 4))
    v = [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)]
    return {"t": wall, "p": [float(pos.get(k, 0.0)) for k in (1, 2, 3)], "v": v}


def read_recording(run_dir: Path) -> Recording:
    """Read the JSON topics of a run folder's MCAP (an unfinished file too, streamed)."""
    path = find_mcap(run_dir)
    states: dict[str, Stream] = {}
    poses: dict[str, Stream] = {}
    mocap: dict[str, Stream] = {}
    counts: dict[str, int] = {}
    info: dict[str, Any] | None = None
    decoder = msgspec.json.Decoder()
    complete = True
    with path.open("rb") as f:
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise ValueError("no summary")
            messages = reader.iter_messages(log_time_order=True)
        except Exception:  # an MCAP cut short (SIGKILL): stream what was written
            f.seek(0)
            complete = False
            messages = NonSeekingReader(f).iter_messages(log_time_order=False)
        try:
            for _schema, channel, msg in messages:
                topic = channel.topic
                counts[topic] = counts.get(topic, 0) + 1
                parts = topic.split("/")
                if parts[1:2] == ["drones"] and parts[3:] == ["mocap"] and \
                        channel.message_encoding == "protobuf":
                    m = mocap.setdefault(parts[2], Stream())
                    m.w.append(msg.log_time * 1e-9)
                    m.docs.append(mocap_doc(msg.data, m.w[-1]))
                if channel.message_encoding != "json":
                    continue
                if topic == INFO_TOPIC:
                    info = decoder.decode(msg.data)
                elif len(parts) == 4 and parts[1] == "agents" and parts[3] in ("state", "pose"):
                    box = states if parts[3] == "state" else poses
                    s = box.setdefault(parts[2], Stream())
                    s.w.append(msg.log_time * 1e-9)
                    s.docs.append(decoder.decode(msg.data))
        except Exception as e:  # a torn last chunk: keep what was read before it
            if complete:
                raise RecordingError(f"{path}: not a readable MCAP file ({e})") from None
            if info is None:  # nothing usable before the damage: one line, not two
                raise RecordingError(f"{path}: not a readable viscover recording ({e})") \
                    from None
            _log.warning("%s: recording cut short (%s); using what precedes", path, e)
    if info is None:
        raise RecordingError(f"{path}: no {INFO_TOPIC} message; not a viscover recording")
    events, skipped = _read_events(run_dir)
    return Recording(info, states, poses, counts, events, complete, mocap, skipped)


def _align(rec: Recording) -> tuple[dict[str, float], float, float]:
    """Offset [s] of each agent's mission clock on the common axis, the time scale s
    [mission s / wall s] and the axis origin: a wall time w is at τ = s·w − origin (see
    module doc)."""
    slopes, samples = [], {}
    for aid in set(rec.states) | set(rec.poses):
        w = np.concatenate([np.asarray(s.w) for s in (rec.states.get(aid), rec.poses.get(aid))
                            if s is not None and s.docs])
        t = np.concatenate([s.t for s in (rec.states.get(aid), rec.poses.get(aid))
                            if s is not None and s.docs])
        samples[aid] = (w, t)
        if w.size >= 2 and np.ptp(w) > 0.0:
            wc = w - w.mean()
            slopes.append(float(wc @ (t - t.mean()) / (wc @ wc)))
    scale = float(np.median(slopes)) if slopes and np.median(slopes) > 0 else 1.0
    offsets = {aid: float(np.median(t - scale * w)) for aid, (w, t) in samples.items()}
    for aid, m in rec.mocap.items():  # mocap only: t = s·w, on the axis of the others
        if aid not in samples and m.docs:
            samples[aid] = (np.asarray(m.w), scale * np.asarray(m.w))
            offsets[aid] = 0.0
    start = min((float(np.min(samples[a][1])) - o for a, o in offsets.items()), default=0.0)
    return {aid: o + start for aid, o in offsets.items()}, scale, start


def _hold(tau: Array, grid: Array) -> NDArray[np.intp]:
    """Index of the latest sample at or before each grid time (the first before it)."""
    return np.clip(np.searchsorted(tau, grid, side="right") - 1, 0, max(tau.size - 1, 0))


def _owned_masks(docs: list[dict[str, Any]], ids_sorted: NDArray[np.int64],
                 order: NDArray[np.intp]) -> NDArray[np.bool_]:
    """(states, m) masks of the landmarks each state owns (rows in scenario order)."""
    lists = [np.asarray(d["owned"], dtype=np.int64) for d in docs]
    lens = np.array([x.size for x in lists], dtype=np.intp)
    flat = np.concatenate(lists) if lists else np.zeros(0, dtype=np.int64)
    rows = np.repeat(np.arange(len(lists)), lens)
    pos = np.clip(np.searchsorted(ids_sorted, flat), 0, max(ids_sorted.size - 1, 0))
    ok = ids_sorted[pos] == flat if ids_sorted.size else np.zeros(0, dtype=bool)
    mask = np.zeros((len(lists), ids_sorted.size), dtype=bool)
    mask[rows[ok], order[pos[ok]]] = True
    return mask


def _forward_fill(owners: NDArray[np.intp], initial: NDArray[np.intp]) -> NDArray[np.intp]:
    """Owners (T, m) with each -1 replaced by the landmark's previous owner (or ``initial``)."""
    rows = np.where(owners >= 0, np.arange(owners.shape[0])[:, None], -1)
    last = np.maximum.accumulate(rows, axis=0)
    cols = np.broadcast_to(np.arange(owners.shape[1]), owners.shape)
    filled = np.where(last >= 0, owners[np.maximum(last, 0), cols], initial[None, :])
    return filled.astype(np.intp)


def _trades(rec: Recording, agents: list[str], offsets: dict[str, float], grid: Array,
            owners: NDArray[np.intp], coverage: Array, ids: NDArray[np.int64]
            ) -> list[TradeEvent]:
    """Trades from the per-partner counters of the states (see the module docstring)."""
    when: dict[tuple[str, str], Array] = {}
    for a, s in rec.states.items():
        tau = s.t - offsets.get(a, 0.0)
        partners = {b for d in s.docs for b in d.get("trades_with", {})}
        for b in partners:
            c = np.maximum.accumulate(np.array([d["trades_with"].get(b, 0) for d in s.docs]))
            ks = np.arange(1, int(c[-1]) + 1)
            when[(a, b)] = tau[np.searchsorted(c, ks)]
    out: list[TradeEvent] = []
    for (a, b), ta in when.items():
        if a > b and (b, a) in when:
            continue
        tb = when.get((b, a), np.full(ta.size, np.inf))
        n = max(ta.size, tb.size)
        ta = np.pad(ta, (0, n - ta.size), constant_values=np.inf)
        tb = np.pad(tb, (0, n - tb.size), constant_values=np.inf)
        for k in range(n):  # a loop over the pair's trades
            first, later = min(ta[k], tb[k]), max(ta[k], tb[k])
            later = first if not np.isfinite(later) else later
            ini, par = (a, b) if ta[k] <= tb[k] else (b, a)
            i, j = agents.index(ini), agents.index(par)
            k0 = max(int(np.searchsorted(grid, first)) - 1, 0)
            k1 = min(int(np.searchsorted(grid, later, side="right")), grid.size - 1)
            before, after = owners[k0], owners[k1]
            out.append(TradeEvent(
                t=float(first), initiator=ini, partner=par,
                to_partner=ids[(before == i) & (after == j)].tolist(),
                to_initiator=ids[(before == j) & (after == i)].tolist(),
                gain=float(coverage[k1] - coverage[k0])))
    return sorted(out, key=lambda e: e.t)


def _visions(p: Array, v: Array, owners: NDArray[np.intp], q: Array, u: Array,
             d_opt: float) -> Array:
    """Eq. 3.8: vision (T, n) of each agent's own set at each sample's pose p [m], v."""
    out = np.zeros(p.shape[:2])
    for k in range(p.shape[0]):  # a loop over samples and agents; the landmarks are batched
        for i in range(p.shape[1]):
            mine = owners[k] == i
            if mine.any():
                out[k, i] = vision_of(p[k, i], v[k, i], q[mine], u[mine], d_opt)
    return out


def to_result(rec: Recording) -> SimResult:
    """The :class:`SimResult` of a recording (see the module docstring)."""
    info = rec.info
    agents = list(info["agents"])
    ids = np.asarray(info["landmark_ids"], dtype=np.int64)
    q = np.asarray(info["q"], dtype=np.float64).reshape(-1, 3)
    u = np.asarray(info["u"], dtype=np.float64).reshape(-1, 3)
    offsets, scale, origin = _align(rec)
    taus = [s.t - offsets[a] for box in (rec.states, rec.poses) for a, s in box.items()
            if s.docs]
    taus += [scale * np.asarray(m.w) - offsets[a] for a, m in rec.mocap.items()
             if m.docs and a not in rec.states and a not in rec.poses]
    span = max((float(x.max()) for x in taus if x.size), default=0.0)
    step = max(float(info.get("dt", 0.1)), span / MAX_SAMPLES)
    grid = np.arange(0.0, span + 0.5 * step, step) if span > 0 else np.array([0.0, step])
    if grid[-1] < span:  # the last sample too: final poses are the last recorded ones
        grid = np.append(grid, span)
    n, m, T = len(agents), ids.size, grid.size
    order = np.argsort(ids, kind="stable")
    initial = np.full(m, -1, dtype=np.intp)
    pos_of = {int(x): j for j, x in enumerate(ids.tolist())}
    for i, a in enumerate(agents):
        js = [pos_of[x] for x in info["initial_partition"].get(a, []) if x in pos_of]
        initial[np.asarray(js, dtype=np.intp)] = i
    start = info.get("initial_poses", {})
    positions, directions = np.zeros((T, n, 3)), np.zeros((T, n, 3))
    directions[..., 0] = 1.0
    for i, a in enumerate(agents):  # a drone never heard stays at its initial pose
        if a in start:
            positions[:, i], directions[:, i] = start[a]["p"], start[a]["v"]
    vision, done = np.zeros((T, n)), np.zeros((T, n), dtype=bool)
    owners = np.full((T, m), -1, dtype=np.intp)
    for i, a in enumerate(agents):
        st, po = rec.states.get(a, Stream()), rec.poses.get(a, Stream())
        docs = st.docs + po.docs
        if not docs and a in offsets:  # mocap only (t = s·w, see _align)
            po = Stream(docs=[dict(d, t=d["t"] * scale) for d in rec.mocap[a].docs])
            docs = po.docs
        if not docs:
            continue
        tau = np.concatenate([st.t, po.t]) - offsets[a]
        srt = np.argsort(tau, kind="stable")
        k = _hold(tau[srt], grid)
        positions[:, i] = np.array([docs[j]["p"] for j in srt], dtype=np.float64)[k]
        directions[:, i] = np.array([docs[j]["v"] for j in srt], dtype=np.float64)[k]
        if st.docs:
            ks = _hold(st.t - offsets[a], grid)
            vision[:, i] = np.array([d["vision"] for d in st.docs])[ks]
            done[:, i] = np.array([bool(d["complete"]) for d in st.docs])[ks]
            owners[_owned_masks(st.docs, ids[order], order)[ks]] = i
    owners = _forward_fill(owners, initial)
    if info.get("visibility", "facing") == "facing":
        vision = _visions(positions, directions, owners, q, u, float(info["d_opt"]))
    coverage = vision.sum(axis=1)
    all_done = done.all(axis=1) & (n > 0)
    t_complete = float(grid[int(np.argmax(all_done))]) if all_done.any() else None
    lo = np.array([-np.inf if x is None else x for x in info["space_lo"]], dtype=np.float64)
    hi = np.array([np.inf if x is None else x for x in info["space_hi"]], dtype=np.float64)
    return SimResult(
        scenario=str(info["scenario"]), seed=int(info.get("seed", 0)),
        planar=bool(info["planar"]), agent_ids=agents, landmark_ids=ids.tolist(), q=q, u=u,
        space_lo=lo, space_hi=hi, d_opt=float(info["d_opt"]), times=grid,
        positions=positions, directions=directions, vision=vision, coverage=coverage,
        owners=owners.astype(np.float64),
        trades=_trades(rec, agents, offsets, grid, owners, coverage, ids),
        complete=t_complete is not None, t_complete=t_complete,
        visibility=str(info.get("visibility", "facing")), clock_offsets=offsets,
        time_scale=scale, wall_origin=origin / scale)
