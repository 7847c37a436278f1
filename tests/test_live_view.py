"""The Foxglove live view (:mod:`agent.mission.live`) with a real WebSocket client.

A recorder serves an in-memory mission live; clients join after the start, speaking the
SDK's subprotocol ``foxglove.sdk.v1`` or the older ``foxglove.websocket.v1`` (older Foxglove
and Lichtblick: HTTP 400 from the SDK alone), subscribe to the latched topics and get their
last message at once, and get a drone's FrameTransform when it moves. The SDK's own log
records go to our logger, not to stderr nor to the root logger.
"""

from __future__ import annotations

import base64
import json
import logging
import socket
import struct
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.exceptions import InvalidStatus
from websockets.sync.client import ClientConnection, connect
from websockets.typing import Subprotocol

from agent.config.parse import load_scenario
from agent.mission.live import answer_legacy, offer_sdk_protocol
from agent.mission.recorder import Recorder
from agent.net.memory import MemoryNetwork
from agent.storage import recording as fmt
from agent.wire import keys
from agent.wire.peer import Pose
from tests.conftest import scenario_path
from tests.test_status_identity import PUB

LATCHED = (fmt.INFO_TOPIC, fmt.MISSION_TOPIC, fmt.LANDMARKS_TOPIC)


def protobuf_decoder(name: str, schema: bytes) -> Callable[[bytes], Any]:
    """A decoder of message ``name`` built from its FileDescriptorSet (google.protobuf, not
    our code)."""
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))

    def decode(data: bytes) -> Any:
        return cls.FromString(data)

    return decode


@pytest.fixture
def live(tmp_path: Path) -> Iterator[tuple[Recorder, MemoryNetwork]]:
    """The cube's mission recorded and served live on a free loopback port."""
    net = MemoryNetwork()
    rec = Recorder(net.transport("rec"), load_scenario(str(scenario_path("cube_6_2"))), "m",
                   tmp_path, pose_hz=1e6, scene_hz=1e6, live=0)
    try:
        yield rec, net
    finally:
        rec.close()


def _join(port: int, protocol: str) -> ClientConnection:
    """A client speaking ``protocol`` (use it in a ``with``)."""
    return connect(f"ws://127.0.0.1:{port}", subprotocols=[Subprotocol(protocol)],
                   open_timeout=5)


def _hello(ws: ClientConnection, protocol: str) -> dict[str, dict[str, Any]]:
    """The server's hello to a client speaking ``protocol``: the channels by topic."""
    assert ws.subprotocol == protocol
    assert json.loads(ws.recv(timeout=5))["op"] == "serverInfo"
    channels: dict[str, dict[str, Any]] = {}
    while not set(LATCHED) <= set(channels):
        msg = json.loads(ws.recv(timeout=5))
        if msg["op"] == "advertise":
            channels.update({c["topic"]: c for c in msg["channels"]})
    return channels


def _receive(ws: ClientConnection, want: int, timeout: float = 5.0) -> dict[int, bytes]:
    """Message data by subscription id until ``want`` subscriptions have one each."""
    got: dict[int, bytes] = {}
    deadline = time.monotonic() + timeout
    while len(got) < want:
        msg = ws.recv(timeout=max(deadline - time.monotonic(), 0.01))
        if isinstance(msg, bytes) and msg[0] == 1:  # MessageData: op, sub id, log time, data
            sub, _log_time = struct.unpack_from("<IQ", msg, 1)
            got.setdefault(sub, msg[13:])
    return got


def _decode(channel: dict[str, Any], data: bytes) -> Any:
    """A received message: JSON, or protobuf with the advertised schema."""
    if channel["encoding"] == "json":
        return json.loads(data)
    assert channel["encoding"] == "protobuf"
    return protobuf_decoder(channel["schemaName"], base64.b64decode(channel["schema"]))(data)


@pytest.mark.parametrize("protocol", ["foxglove.sdk.v1", "foxglove.websocket.v1"])
def test_a_late_client_of_either_subprotocol_gets_the_latched_topics(
        live: tuple[Recorder, MemoryNetwork], protocol: str) -> None:
    rec, net = live
    assert rec.server is not None
    time.sleep(0.3)  # the mission started well before the viewer joins
    with _join(rec.server.port, protocol) as ws:
        channels = _hello(ws, protocol)
        subs = {k: channels[t] for k, t in enumerate(LATCHED, 1)}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": k, "channelId": c["id"]} for k, c in subs.items()]}))
        got = _receive(ws, len(subs))
        info = _decode(subs[1], got[1])
        assert info["scenario"] == "cube_6_2" and info["agents"] == ["A", "B", "C"]
        space = _decode(subs[2], got[2])
        assert [e.id for e in space.entities] == ["mission_space"]
        assert len(space.entities[0].lines[0].points) == 24  # the box's 12 edges
        cloud = _decode(subs[3], got[3])
        assert cloud.point_stride * len(info["landmark_ids"]) == len(cloud.data)
        # a drone's frames, live: subscribe, then the drone moves
        tf = channels[fmt.frame_topic("B")]
        assert tf["schemaName"] == "foxglove.FrameTransform"
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 9,
                                                                  "channelId": tf["id"]}]}))
        time.sleep(0.2)
        net.transport("B").publish(keys.pose_key("m", "B"), PUB.encode(Pose(
            sender="B", seq=1, t=1.0, p=(1.0, -0.5, 2.0), v=(0.0, 1.0, 0.0))))
        frame = _decode(tf, _receive(ws, 1)[9])
        assert (frame.parent_frame_id, frame.child_frame_id) == ("world", "drone/B")
        assert (frame.translation.x, frame.translation.y, frame.translation.z) == (
            1.0, -0.5, 2.0)
    if protocol == "foxglove.websocket.v1":
        assert rec.server.front.legacy_clients == 1


def test_a_client_without_a_foxglove_subprotocol_is_refused(
        live: tuple[Recorder, MemoryNetwork]) -> None:
    rec, _net = live
    assert rec.server is not None
    with pytest.raises(InvalidStatus) as err:
        connect(f"ws://127.0.0.1:{rec.server.port}", subprotocols=[Subprotocol("chat")],
                open_timeout=5)
    assert err.value.response.status_code == 400


def test_the_request_rewrite() -> None:
    head = (b"GET / HTTP/1.1\r\nHost: h\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n"
            b"sec-websocket-protocol: x\r\n\r\n")
    new, legacy = offer_sdk_protocol(head)
    assert legacy and new == (b"GET / HTTP/1.1\r\nHost: h\r\n"
                              b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n")
    both = (b"GET / HTTP/1.1\r\n"
            b"Sec-WebSocket-Protocol: foxglove.websocket.v1, foxglove.sdk.v1\r\n\r\n")
    assert offer_sdk_protocol(both) == (both, False)  # the SDK picks its own
    other = b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: chat\r\n\r\n"
    assert offer_sdk_protocol(other) == (other, False)
    ok = b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n"
    assert answer_legacy(ok) == (b"HTTP/1.1 101 Switching Protocols\r\n"
                                 b"Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n")
    refused = b"HTTP/1.1 400 Bad Request\r\n\r\n"
    assert answer_legacy(refused) == refused


class _Collect(logging.Handler):
    """Keeps every record that reaches the logger it is attached to."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def test_the_sdk_logs_to_our_logger(live: tuple[Recorder, MemoryNetwork],
                                    caplog: pytest.LogCaptureFixture) -> None:
    """A viewer that drops its connection makes the SDK log an error: it reaches the root
    logger (where a command's handler would print it) only as a ``viscover.*`` record at
    INFO, never as a record of the SDK's own loggers (printed raw on stderr when nothing
    else is configured)."""
    rec, _net = live
    assert rec.server is not None
    caplog.set_level(logging.DEBUG, logger="viscover")
    root = logging.getLogger()
    seen = _Collect()
    root.addHandler(seen)
    try:
        with _join(rec.server.port, "foxglove.sdk.v1") as ws:
            _hello(ws, "foxglove.sdk.v1")
            ws.socket.shutdown(socket.SHUT_RDWR)  # gone without a closing handshake
        deadline = time.monotonic() + 5.0
        ours: list[logging.LogRecord] = []
        while not ours and time.monotonic() < deadline:
            time.sleep(0.05)
            ours = [r for r in seen.records if r.name == "viscover.agent.mission.live.sdk"
                    and r.levelno == logging.INFO]
    finally:
        root.removeHandler(seen)
    assert ours, [(r.name, r.getMessage()) for r in seen.records]
    assert "foxglove-sdk" in ours[0].getMessage()
    assert not [r for r in seen.records if r.name.split(".")[0] in ("foxglove", "tungstenite")]
