"""The ROS 2 bridge on a real Zenoh router: a stand-in mission (three agents' liveliness, poses,
states, one drone's mocap) goes in; every bridged topic comes out on rmw_zenoh's keys with its
attachment and liveliness token, decodes with rosbags' deserializer to the expected values, is
discovered and read by an independent client (zenoh-ros2-sdk, definitions handed to it,
offline) and lands in the bag; land / stop published by that client reach the agents."""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pytest
import zenoh
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.stores.ros2_jazzy import (
    diagnostic_msgs__msg__DiagnosticArray as DiagnosticArray,
)
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__PoseStamped as PoseStamped
from rosbags.typesys.stores.ros2_jazzy import rcl_interfaces__msg__Log as Log
from rosbags.typesys.stores.ros2_jazzy import tf2_msgs__msg__TFMessage as TFMessage
from rosbags.typesys.stores.ros2_jazzy import (
    visualization_msgs__msg__MarkerArray as MarkerArray,
)
from zenoh_ros2_sdk import discovery
from zenoh_ros2_sdk.publisher import ROS2Publisher
from zenoh_ros2_sdk.session import ZenohSession
from zenoh_ros2_sdk.subscriber import ROS2Subscriber

from agent.config.parse import load_scenario
from agent.config.scenario import Scenario
from agent.net.router import client_config
from agent.net.transport import ZenohTransport
from agent.wire import keys
from agent.wire.codec import Codec
from agent.wire.commands import ACK_CODEC, COMMAND_CODEC, CommandAck, MissionCommand
from agent.wire.ground import MOCAP_CODEC, MocapPose
from agent.wire.peer import AgentState, Counters, Pose, Publication, pack
from groundstation.ros2 import frames, rmw
from groundstation.ros2 import typesupport as ts
from groundstation.ros2.bag import BagWriter
from groundstation.ros2.bridge import Bridge
from groundstation.ros2.names import Names
from groundstation.ros2.node import RosNode
from tests.conftest import scenario_path, wait_until

M = "rosb"
PUB: Codec[Publication] = Codec(Publication)
READER = get_typestore(Stores.ROS2_JAZZY)
#: camera positions [m] and unit directions of the stand-in agents
POSES = {"A": ((-2.0, 2.0, 0.0), (1.0, 0.0, 0.0)), "B": ((2.0, 2.0, 0.0), (0.0, -1.0, 0.0)),
         "C": ((0.0, -2.0, 0.0), (0.6, 0.8, 0.0))}
MOCAP_Q = (math.cos(0.2), 0.0, 0.0, math.sin(0.2))  # (w, x, y, z): yaw 0.4 rad
T = TypeVar("T")


def decode(payload: bytes, typename: str, kind: type[T]) -> T:
    """CDR ``payload`` decoded by rosbags' deserializer, a rosbags ``kind``."""
    out = READER.deserialize_cdr(payload, typename)
    assert isinstance(out, kind), out
    return out


class Sample:
    """One received sample: key, CDR payload, attachment bytes."""

    def __init__(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        self.key, self.payload, self.attachment = key, payload, attachment


class Agents:
    """Three stand-in agents of ``sc``: tokens, poses, states, A's mocap; they acknowledge
    every command they hear and keep it in ``commands``."""

    def __init__(self, router: str, sc: Scenario) -> None:
        self.tp = ZenohTransport(client_config(router), node_id="agents")
        self.sc = sc
        self.tokens = [self.tp.declare_liveliness(keys.alive_key(M, a.id)) for a in sc.agents]
        self.seq = 0
        self.commands: list[MissionCommand] = []
        self.tp.subscribe(keys.command_key(M), self._on_command)

    def _on_command(self, key: str, payload: bytes) -> None:
        cmd = COMMAND_CODEC.decode(payload, key)
        if cmd is None:
            return
        self.commands.append(cmd)
        for aid in cmd.targets:
            self.tp.publish(keys.command_ack_key(M, aid), ACK_CODEC.encode(CommandAck(
                sender=aid, commander=cmd.sender, seq=cmd.seq, command=cmd.command)))

    def tick(self) -> None:
        self.seq += 1
        ids = np.asarray(self.sc.landmark_ids)
        for a in self.sc.agents:
            p, v = POSES[a.id]
            self.tp.publish(keys.pose_key(M, a.id), PUB.encode(
                Pose(sender=a.id, seq=self.seq, t=0.1 * self.seq, p=p, v=v)))
            owned = pack({int(i): 0 for i in ids[a.landmarks]})
            self.tp.publish(keys.state_key(M, a.id), PUB.encode(AgentState(
                sender=a.id, incarnation=1, seq=self.seq, t=0.1 * self.seq, p=p, v=v,
                phase="optimising", owned=owned, held=pack({}), vision=0.5,
                counters=Counters(), partners=[], pending=[], trades_with={})))
        self.tp.publish(keys.mocap_key(M, "A"), MOCAP_CODEC.encode(MocapPose(
            drone="A", seq=self.seq, t=0.1 * self.seq, p=[-2.0, 2.0, 0.1], q=list(MOCAP_Q),
            v=[0.0, 0.0, 0.0])))

    def close(self) -> None:
        self.tp.close()


class Setup:
    """A bridge of the hexagon mission, its stand-in agents and a raw reader of domain 0."""

    def __init__(self, router: str, tmp: Path, distro: rmw.Distro = "jazzy") -> None:
        self.sc = load_scenario(scenario_path("hexagon_5_3"))
        # The raw reader listens before the bridge starts: the watch's first events (the
        # drones' tokens seen) are published once, at once (a reader subscribed after them
        # missed them on a loaded CI machine).
        self._reading = contextlib.ExitStack()  # the raw reader's session and subscriber
        self.reader = self._reading.enter_context(zenoh.open(client_config(router)))
        self.got: dict[str, list[Sample]] = {}
        self._lock = threading.Lock()
        self.sub = self._reading.enter_context(self.reader.declare_subscriber("0/**", self._on))
        self.agents = Agents(router, self.sc)
        self.tp = ZenohTransport(client_config(router), node_id="bridge")
        self.node = RosNode(self.tp.session, 0, distro, "/viscover")
        self.bag = BagWriter(tmp / "bag")
        self.bridge = Bridge(self.tp, self.sc, M, node=self.node, bag=self.bag,
                             names=Names("/viscover"), status_period_s=0.2,
                             landmarks_period_s=0.3, command_timeout_s=3.0)

    def _on(self, s: zenoh.Sample) -> None:
        att = s.attachment.to_bytes() if s.attachment is not None else None
        topic = "/" + str(s.key_expr).split("/", 1)[1].rsplit("/", 2)[0]
        with self._lock:
            self.got.setdefault(topic, []).append(
                Sample(str(s.key_expr), s.payload.to_bytes(), att))

    def samples(self, topic: str) -> list[Sample]:
        with self._lock:
            return list(self.got.get(topic, []))

    def wait_for(self, pred: Callable[[], object], timeout_s: float = 10.0) -> None:
        if not wait_until(pred, timeout_s, poll_s=0.05, poke=self.agents.tick):
            pytest.fail(f"not within {timeout_s} s; topics so far: {sorted(self.got)}")

    def tokens(self) -> list[str]:
        return [str(r.ok.key_expr) for r in self.reader.liveliness().get("@ros2_lv/0/**",
                                                                          timeout=2.0)
                if r.ok is not None]

    def close(self) -> None:
        self._reading.close()  # undeclares the subscriber, closes the reader's session
        self.bridge.close()
        self.node.close()
        self.bag.close()
        self.tp.close()
        self.agents.close()


@pytest.fixture
def setup(router: str, tmp_path: Path) -> Iterator[Setup]:
    s = Setup(router, tmp_path)
    yield s
    s.close()


@pytest.fixture
def sdk(router: str) -> Iterator[dict[str, Any]]:
    """The independent client's connection arguments; its shared session closed after."""
    port = int(router.rsplit(":", 1)[1])
    yield {"router_ip": "127.0.0.1", "router_port": port, "domain_id": 0}
    inst = ZenohSession._instance
    if inst is not None:
        ZenohSession._instance = None
        inst.session.close()


def topic_types(s: Setup) -> dict[str, str]:
    """Every announced topic of the bridge and its type."""
    return dict(s.bridge.model.topics())


def fed(s: Setup) -> dict[str, str]:
    """The topics the stand-in mission feeds (mocap only for A)."""
    return {t: ty for t, ty in topic_types(s).items() if t not in ("/viscover/B/mocap",
                                                                   "/viscover/C/mocap")}


def test_every_topic_on_rmw_zenoh_keys_with_attachments(setup: Setup) -> None:
    s = setup
    expected = topic_types(s)
    s.wait_for(lambda: all(len(s.samples(t)) >= 3 for t in fed(s)))
    tokens = s.tokens()
    by_topic = {}
    for tok in tokens:
        parts = tok.split("/")
        if parts[5] == rmw.PUBLISHER:
            by_topic[parts[9].replace("%", "/")] = tok
    assert rmw.node_token(0, s.node.zid, 0, "/viscover", "bridge") in tokens
    for topic, typename in expected.items():
        dds, h = rmw.dds_type_name(typename), ts.rihs01(typename)
        token = by_topic[topic]
        assert token == rmw.entity_token(0, s.node.zid, 0, int(token.split("/")[4]),
                                         rmw.PUBLISHER, "/viscover", "bridge", topic, dds, h,
                                         rmw.Qos())
        seqs = []
        for smp in s.samples(topic):
            assert smp.key == rmw.data_key(0, topic, dds, h)
            att = rmw.decode_attachment(smp.attachment)
            assert att is not None and len(smp.attachment or b"") == 33
            assert att.gid == rmw.gid_of(token)
            assert abs(att.stamp_ns - time.time_ns()) < 30e9
            seqs.append(att.sequence)
            READER.deserialize_cdr(smp.payload, typename)  # every sample decodes
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
        assert (topic in fed(s)) == bool(seqs) and all(q >= 1 for q in seqs)
    subs = {t.split("/")[9].replace("%", "/") for t in tokens if t.split("/")[5] == "MS"}
    assert subs == {"/viscover/land", "/viscover/stop"}


def test_topics_decode_to_the_mission(setup: Setup) -> None:
    s = setup

    def last(topic: str, typename: str, kind: type[T]) -> T:
        return decode(s.samples(topic)[-1].payload, typename, kind)

    def phases_known() -> bool:  # the status view has heard every drone's state
        st = last("/viscover/status", ts.DIAGNOSTIC_ARRAY, DiagnosticArray).status[:3]
        return all(any(kv.key == "phase" and kv.value == "optimising" for kv in x.values)
                   for x in st)

    s.wait_for(lambda: s.samples("/viscover/status") and s.samples("/viscover/events")
               and len(s.samples("/tf")) >= 6 and s.samples("/viscover/landmarks")
               and phases_known())

    pose = last("/viscover/B/pose", ts.POSE_STAMPED, PoseStamped)
    o = pose.pose.orientation
    assert (pose.pose.position.x, pose.pose.position.y) == (2.0, 2.0)
    assert np.allclose(frames.rotate((o.x, o.y, o.z, o.w), (1, 0, 0)), POSES["B"][1])
    mocap = last("/viscover/A/mocap", ts.POSE_STAMPED, PoseStamped)
    assert np.isclose(mocap.pose.orientation.z, math.sin(0.2))
    assert np.isclose(mocap.pose.orientation.w, math.cos(0.2))
    frames_seen = set()
    for smp in s.samples("/tf"):
        for t in decode(smp.payload, ts.TF_MESSAGE, TFMessage).transforms:
            frames_seen.add((t.header.frame_id, t.child_frame_id))
    assert {("world", "A"), ("A", "A/camera"), ("world", "B"), ("B", "B/camera"),
            ("world", "C"), ("C", "C/camera")} <= frames_seen
    lm = last("/viscover/landmarks", ts.MARKER_ARRAY, MarkerArray).markers[0]
    assert np.allclose([[p.x, p.y, p.z] for p in lm.points], s.sc.q)
    owner = {int(lid): k for k, a in enumerate(s.sc.agents)
             for lid in np.asarray(s.sc.landmark_ids)[a.landmarks]}
    for lid, c in zip(s.sc.landmark_ids, lm.colors, strict=True):
        from groundstation.ros2.messages import drone_rgba
        assert np.allclose((c.r, c.g, c.b), drone_rgba(owner[int(lid)])[:3], atol=1e-6)
    fr = last("/viscover/frusta", ts.MARKER_ARRAY, MarkerArray)
    assert {(mk.ns, mk.id) for mk in fr.markers} >= {("frustum", 0), ("label", 0)}
    status = last("/viscover/status", ts.DIAGNOSTIC_ARRAY, DiagnosticArray)
    assert [st.name for st in status.status] == ["viscover/A", "viscover/B", "viscover/C",
                                                 "viscover/mission"]
    assert all(kv.value == "optimising" for st in status.status[:3] for kv in st.values
               if kv.key == "phase")
    texts = [decode(x.payload, ts.LOG, Log).msg for x in s.samples("/viscover/events")]
    assert any("first state" in t for t in texts)


def test_an_independent_client_discovers_and_reads_the_topics(setup: Setup,
                                                                sdk: dict[str, Any]) -> None:
    s = setup
    got: list[Any] = []
    sub = ROS2Subscriber("/viscover/C/pose", ts.POSE_STAMPED, got.append,
                         msg_definition=ts.msgdef(ts.POSE_STAMPED),
                         type_hash=ts.rihs01(ts.POSE_STAMPED), **sdk)
    try:
        listed = dict(discovery.get_topic_names_and_types(timeout=2.0, **sdk))
        for topic, typename in topic_types(s).items():
            assert listed[topic] == [typename]
        assert listed["/viscover/land"] == [ts.STRING]
        s.wait_for(lambda: got)
        assert (got[-1].pose.position.x, got[-1].pose.position.y) == (0.0, -2.0)
        assert got[-1].header.frame_id == "world"
    finally:
        sub.close()


def test_land_from_ros_reaches_the_agents(setup: Setup, sdk: dict[str, Any]) -> None:
    s = setup
    s.wait_for(lambda: all(d.live for d in s.bridge.watch.drones.values()))
    pub = ROS2Publisher("/viscover/land", ts.STRING, msg_definition="string data",
                        type_hash=ts.rihs01(ts.STRING), **sdk)
    try:
        if not wait_until(lambda: s.agents.commands, 5.0, poll_s=0.2,
                          poke=lambda: pub.publish(data="B")):
            pytest.fail("no command reached the agents")
    finally:
        pub.close()
    cmd = s.agents.commands[0]
    assert (cmd.command, cmd.targets, cmd.sender) == ("land", ["B"], "ros2")

    def sent() -> list[str]:
        return [m for x in s.samples("/viscover/events")
                if "land sent to B" in (m := decode(x.payload, ts.LOG, Log).msg)]

    s.wait_for(lambda: sent())
    assert sent()[0].endswith("acknowledged")


def test_humble_keys_and_a_humble_publisher(router: str, tmp_path: Path) -> None:
    s = Setup(router, tmp_path, distro="humble")
    try:
        s.wait_for(lambda: s.samples("/viscover/A/pose"))
        assert s.samples("/viscover/A/pose")[0].key == \
            f"0/viscover/A/pose/{rmw.dds_type_name(ts.POSE_STAMPED)}/TypeHashNotSupported"
        assert all(t.split("/")[11] == "TypeHashNotSupported" for t in s.tokens()
                   if len(t.split("/")) > 11)
        # a Humble node's stop (its key carries no hash) is taken too
        key = rmw.data_key(0, "/viscover/stop", rmw.dds_type_name(ts.STRING),
                           rmw.HUMBLE_TYPE_HASH)
        from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__String as String
        cdr = ts.serialize(String(data="all"), ts.STRING)
        att = rmw.encode_attachment(1, time.time_ns(), bytes(16))
        s.wait_for(lambda: all(d.live for d in s.bridge.watch.drones.values()))
        if not wait_until(lambda: s.agents.commands, 5.0, poll_s=0.2,
                          poke=lambda: s.reader.put(key, cdr, attachment=att)):
            pytest.fail("the Humble stop did not reach the agents")
        assert s.agents.commands[0].command == "stop"
        assert sorted(s.agents.commands[0].targets) == ["A", "B", "C"]
    finally:
        s.close()


def test_bad_payloads_are_counted_not_raised(setup: Setup) -> None:
    s = setup
    s.wait_for(lambda: s.samples("/viscover/A/pose"))
    before = s.bridge.summary()["rejected"]
    s.agents.tp.publish(keys.pose_key(M, "A"), b"\xc1 not msgpack")
    s.agents.tp.publish(keys.mocap_key(M, "A"), b"")
    s.reader.put(rmw.data_key(0, "/viscover/land", rmw.dds_type_name(ts.STRING), "x"),
                 b"\x00\x01\x00\x00\xff\xff\xff\x7f", attachment=bytes(33))
    s.wait_for(lambda: s.bridge.summary()["rejected"] >= before + 3)
    assert s.agents.commands == []


def test_the_bag_opens_with_the_right_counts(router: str, tmp_path: Path) -> None:
    s = Setup(router, tmp_path)
    try:
        s.wait_for(lambda: all(len(s.samples(t)) >= 2 for t in fed(s)))
    finally:
        s.close()
    counts = dict(s.bag.counts)
    assert set(counts) == set(fed(s))
    with Reader(tmp_path / "bag") as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == fed(s)
        assert {c.topic: c.msgcount for c in reader.connections} == counts
        assert reader.message_count == sum(counts.values())
        assert all(c.digest == ts.rihs01(c.msgtype) for c in reader.connections)
        seen: dict[str, int] = {}
        for conn, stamp, raw in reader.messages():
            READER.deserialize_cdr(raw, conn.msgtype)
            seen[conn.topic] = seen.get(conn.topic, 0) + 1
            assert abs(stamp - time.time_ns()) < 120e9
        assert seen == counts
    assert list((tmp_path / "bag").glob("*.mcap"))
