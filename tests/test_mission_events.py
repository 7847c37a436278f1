"""Mission events as typed Structs (:mod:`agent.storage.events`): every kind round-trips
through JSON; a line written by the dict-based events before them decodes to the same keys and
values; malformed lines are counted, logged once and skipped, never raised; and what a whole
in-memory mission emits through the watch and the recorder all reads back (the replay too,
a torn last line counted)."""

from __future__ import annotations

import json
import logging
import time
import typing
from pathlib import Path
from typing import Any

import msgspec
import pytest

from agent.mission.recorder import Recorder, line_event
from agent.runtime.shell.runtime import AgentConfig
from agent.sim.replay import read_recording
from agent.storage import recording as fmt
from agent.storage.events import (
    EVENT_TYPES,
    EVENTS_SCHEMA,
    Event,
    EventDecoder,
    Failsafe,
    Flight,
    Level,
    LogLine,
    Process,
    ProcessError,
    Trade,
    encode_event,
    read_events,
)
from agent.testing.memsim import MemoryMission
from agent.wire.codec import REASON_SCHEMA, REASON_UNDECODABLE
from tests.agent_helpers import thesis

#: (kind, level, the kind's fields) of one event of each kind as the code emits them (a
#: legacy trade without its terms and a process line without pid too)
SAMPLES: list[tuple[str, Level, dict[str, Any]]] = [
    ("first_state", "info", {"incarnation": 1}),
    ("restart", "warning", {"incarnation": 2}),
    ("phase", "info", {"phase": "converged", "previous": "optimising"}),
    ("trade", "info", {"partner": "B", "count": 1, "gained": [2], "given": [6],
                       "trade": "A:1:1", "role": "initiator", "n": 1}),
    ("trade", "info", {"partner": "B", "count": 2, "gained": [], "given": [4]}),
    ("trade_gap", "info", {"count": 2}),
    ("no_trade", "info", {"count": 3}),
    ("fault", "warning", {"what": "timeouts", "count": 4}),
    ("complete", "info", {}),
    ("mission_complete", "info", {"complete": True}),
    ("join", "info", {}),
    ("leave", "warning", {}),
    ("mocap", "warning", {"state": "stale"}),
    ("command", "warning", {"command": "land", "targets": ["A", "C"], "seq": 7}),
    ("ack", "info", {"command": "stop", "commander": "op", "seq": 7}),
    ("violation", "error", {}),
    ("process", "info", {"pid": 4321}),
    ("process", "warning", {}),
    ("crash", "error", {"status": 1}),
    ("exit", "info", {"status": 0}),
    ("launch_end", "warning", {"status": 130}),
    ("flight", "info", {}),
    ("failsafe", "warning", {}),
    ("error", "error", {}),
    ("log", "warning", {}),
    ("recording", "info", {"path": "/runs/x/recording.mcap"}),
    ("recording_end", "info", {"messages": {"/events": 3, "/landmarks": 2}, "rejected": 1}),
    ("command_refused", "warning", {"command": "land"}),
    ("command_sent", "info", {"command": "stop", "targets": ["A", "B"],
                              "unacknowledged": ["B"]}),
    ("capture", "info", {"landmarks": [1, 3], "captured": 2, "total": 6}),
]


def old_event(source: str, kind: str, text: str, level: str = "info",
              **fields: Any) -> dict[str, Any]:
    """The event as the dict-based ``agent.mission.watch.event`` built it."""
    return {"time": time.time(), "source": source, "kind": kind, "level": level,
            "text": text, **fields}


def old_line(ev: dict[str, Any], started: float) -> str:
    """The line of ``events.jsonl`` the dict-based recorder wrote for ``ev``."""
    ev = {**ev, "t": round(float(ev["time"]) - started, 6)}
    return json.dumps(ev, default=str)


def test_the_union_names_every_kind_once_and_the_samples_cover_it() -> None:
    assert typing.get_args(Event) == EVENT_TYPES
    kinds = [cls.__struct_config__.tag for cls in EVENT_TYPES]
    assert len(set(kinds)) == len(kinds)
    assert {k for k, _l, _f in SAMPLES} == set(kinds)


@pytest.mark.parametrize(("kind", "level", "fields"), SAMPLES,
                         ids=[f"{k}-{i}" for i, (k, _l, _f) in enumerate(SAMPLES)])
def test_an_old_line_decodes_and_encodes_back_to_the_same_keys_and_values(
        kind: str, level: str, fields: dict[str, Any]) -> None:
    old = old_event("A", kind, f"A: a {kind}", level, **fields)
    line = old_line(old, started=old["time"] - 1.5)
    dec = EventDecoder()
    ev = dec.decode(line)
    assert ev is not None and dec.counter.total == 0
    assert (ev.kind, ev.source, ev.level, ev.text, ev.t) == (kind, "A", level, f"A: a {kind}",
                                                             1.5)
    assert ev.time == old["time"] and ev.schema == EVENTS_SCHEMA
    for name, value in fields.items():
        assert getattr(ev, name) == value
    assert json.loads(encode_event(ev)) == json.loads(line)  # same keys, same values


@pytest.mark.parametrize(("kind", "level", "fields"), SAMPLES,
                         ids=[f"{k}-{i}" for i, (k, _l, _f) in enumerate(SAMPLES)])
def test_every_kind_round_trips_through_json(kind: str, level: Level,
                                             fields: dict[str, Any]) -> None:
    (cls,) = [c for c in EVENT_TYPES if c.__struct_config__.tag == kind]
    ev = cls(time=1.7e9 + 0.25, source="B", level=level, text="B: something", **fields)
    raw = encode_event(ev)
    doc = json.loads(raw)
    assert doc["kind"] == kind and {"time", "source", "level", "text"} <= set(doc)
    assert "schema" not in doc and "t" not in doc  # at their defaults: not written
    assert msgspec.json.decode(raw, type=Event) == ev
    recorded = msgspec.structs.replace(ev, t=0.5)
    assert msgspec.json.decode(encode_event(recorded), type=Event) == recorded
    if kind == "trade" and "trade" not in fields:  # a legacy trade writes no terms
        assert not {"trade", "role", "n"} & set(doc)


def test_malformed_lines_are_counted_logged_once_and_skipped(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    good = encode_event(Flight(time=1.0, source="A", level="info", text="A: armed")).decode()
    lines = [
        good,
        "{not json",
        json.dumps({"time": 1.0, "source": "A", "kind": "teleport", "level": "info",
                    "text": "?"}),  # unknown kind
        json.dumps({"time": 1.0, "source": "A", "kind": "no_trade", "level": "info",
                    "text": "x", "count": "three"}),  # wrong type
        json.dumps({"time": 1.0, "source": "A", "kind": "exit", "level": "info",
                    "text": "x"}),  # missing required field
        json.dumps({"time": 1.0, "source": "A", "kind": "flight", "level": "loud",
                    "text": "x"}),  # a level that is none
        "[1, 2, 3]",
        "",
        json.dumps({"time": 2.0, "source": "A", "kind": "flight", "level": "info",
                    "text": "from the future", "schema": 2}),
        good,
        good[:25],  # a torn last line
    ]
    path = tmp_path / fmt.EVENTS_NAME
    path.write_text("\n".join(lines), encoding="utf-8")
    dec = EventDecoder()
    with caplog.at_level(logging.WARNING, logger="viscover.agent.storage.events"):
        events = read_events(path, dec)
    assert [e.text for e in events] == ["A: armed", "A: armed"]
    assert dec.counter.snapshot()["by_reason"] == {REASON_UNDECODABLE: 7, REASON_SCHEMA: 1}
    assert dec.counter.snapshot()["by_key"] == {str(path): 8}
    logged = [r.getMessage() for r in caplog.records if "skipped an event line" in r.message]
    assert len(logged) == 2  # once per reason within the rate limit
    assert "line 2:" in logged[0] and "line 9:" in logged[1]
    assert read_events(tmp_path / "nothing.jsonl") == []


def test_process_output_lines_become_typed_events() -> None:
    cases = {
        "viscover-flight-agent A: armed": (Flight, "info"),
        "viscover-flight-agent A: mocap lost: level hover": (Failsafe, "warning"),
        "viscover-flight-agent A: left the mission": (Failsafe, "error"),
        "viscover: error: no router": (ProcessError, "error"),
        "viscover: stopping": (Process, "warning"),
        "12:00 ERROR agent.x: failsafe tripped": (Failsafe, "error"),
        "12:00 WARNING agent.x: slow tick": (LogLine, "warning"),
    }
    for text, (cls, level) in cases.items():
        ev = line_event("A", text)
        assert type(ev) is cls and ev.level == level and ev.text == text, text
    assert line_event("A", "12:00 INFO agent.x: fine") is None


def test_what_a_whole_mission_emits_reads_back_from_events_jsonl(tmp_path: Path) -> None:
    """hexagon_5_3 in memory, recorded: every event the watch handed its listeners is a line
    of ``events.jsonl`` that decodes to the same event (with ``t``), nothing skipped."""
    sc = thesis("hexagon_5_3")
    m = MemoryMission(sc, tmp_path / "state", seed=3, autostart=False,
                      config=AgentConfig(mission="mem", seed=3))
    out = tmp_path / "run"
    rec = Recorder(m.net.transport("rec"), sc, "mem", out, pose_hz=1.0, scene_hz=1.0)
    emitted: list[Event] = []
    rec.watch.listeners.append(emitted.append)
    try:
        for a in sc.agents:
            m.start(a.id)
        m.run(300.0, until=lambda mm: mm.complete)
        assert m.complete
        m.run(m.net.now + 2.0, until=lambda _m: False)  # the last states reach the watch
    finally:
        m.close()
        rec.close()
    dec = EventDecoder()
    read = read_events(out / fmt.EVENTS_NAME, dec)
    assert dec.counter.total == 0
    assert (read[0].kind, read[-1].kind) == ("recording", "recording_end")
    started = [e.time - e.t for e in read if e.t is not None]  # the recording's start
    assert len(started) == len(read) and max(started) - min(started) < 1e-5
    assert [msgspec.structs.replace(e, t=None) for e in read[1:-1]] == emitted
    kinds = {e.kind for e in emitted}
    assert {"first_state", "phase", "trade", "complete", "mission_complete"} <= kinds, kinds
    assert all(isinstance(e, Trade) and e.role in ("initiator", "responder")
               for e in emitted if e.kind == "trade")
    with (out / fmt.EVENTS_NAME).open("a", encoding="utf-8") as f:
        f.write('{"kind": "trade", "time": 1.0, "sour')  # a torn last line
    back = read_recording(out)
    assert back.events == read and back.events_skipped == 1
