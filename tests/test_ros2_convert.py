"""The ROS 2 bridge's pure parts, without a router: rmw_zenoh's key, token, QoS and attachment
formats against the examples of its docs/design.md and an independent client
(zenoh-ros2-sdk), type hashes, frames, and every message decoded by rosbags' deserializer."""

from __future__ import annotations

import math
import re
import struct
from typing import TypeVar

import numpy as np
import pytest
import xxhash
from rosbags.interfaces import QosDurability, QosHistory, QosReliability
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore
from rosbags.typesys.stores.ros2_jazzy import (
    diagnostic_msgs__msg__DiagnosticArray as DiagnosticArray,
)
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__PoseStamped as PoseStamped
from rosbags.typesys.stores.ros2_jazzy import rcl_interfaces__msg__Log as Log
from rosbags.typesys.stores.ros2_jazzy import tf2_msgs__msg__TFMessage as TFMessage
from rosbags.typesys.stores.ros2_jazzy import (
    visualization_msgs__msg__MarkerArray as MarkerArray,
)
from zenoh_ros2_sdk import keyexpr as sdk_keyexpr
from zenoh_ros2_sdk.attachment import Attachment as SdkAttachment
from zenoh_ros2_sdk.entity import EndpointEntity, EntityKind, NodeEntity
from zenoh_ros2_sdk.utils import compute_type_hash_from_msg

from agent.config.parse import parse_scenario
from agent.mission.watch import DroneRow, MissionView
from agent.storage.events import PhaseChange
from agent.wire.peer import pack_bits
from groundstation.ros2 import frames, messages, rmw
from groundstation.ros2 import typesupport as ts
from groundstation.ros2.model import MissionRos
from groundstation.ros2.names import Names, check_namespace, drone_token, drone_tokens
from tests.conftest import scenario_path

#: Examples of rmw_zenoh's docs/design.md (std_msgs/String on /chatter).
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
STRING_DDS = "std_msgs::msg::dds_::String_"
READER = get_typestore(Stores.ROS2_JAZZY)  # an independent store, decoding every message


T = TypeVar("T")


def decode(msg: object, typename: str, kind: type[T]) -> T:
    """``msg`` through CDR and back with rosbags' deserializer, a rosbags ``kind``."""
    out = READER.deserialize_cdr(ts.serialize(msg, typename), typename)
    assert isinstance(out, kind), out
    return out


# -- rmw_zenoh formats -------------------------------------------------------------------------
def test_data_keys_are_the_documented_examples() -> None:
    assert rmw.dds_type_name(ts.STRING) == STRING_DDS
    assert ts.rihs01(ts.STRING) == STRING_HASH
    assert rmw.data_key(0, "/chatter", STRING_DDS, STRING_HASH) == \
        f"0/chatter/{STRING_DDS}/{STRING_HASH}"
    assert rmw.data_key(0, "/robot1/chatter", STRING_DDS, STRING_HASH) == \
        f"0/robot1/chatter/{STRING_DDS}/{STRING_HASH}"
    assert rmw.type_hash_for(STRING_HASH, "humble") == "TypeHashNotSupported"
    assert rmw.type_hash_for(STRING_HASH, "jazzy") == STRING_HASH
    with pytest.raises(ValueError):
        rmw.dds_type_name("std_msgs/String")


def test_liveliness_tokens_are_the_documented_examples() -> None:
    zid_l, zid_t = "aac3178e146ba6f1fc6e6a4085e77f21", "8b20917502ee955ac4476e0266340d5c"
    assert rmw.node_token(2, zid_l, 0, "/", "listener") == \
        f"@ros2_lv/2/{zid_l}/0/0/NN/%/%/listener"
    assert rmw.entity_token(2, zid_l, 0, 10, rmw.SUBSCRIPTION, "/", "listener", "/chatter",
                            STRING_DDS, STRING_HASH, rmw.Qos(depth=10)) == \
        f"@ros2_lv/2/{zid_l}/0/10/MS/%/%/listener/%chatter/{STRING_DDS}/{STRING_HASH}/::,10:,:,:,,"
    assert rmw.entity_token(2, zid_t, 0, 10, rmw.PUBLISHER, "/", "talker", "/chatter",
                            STRING_DDS, STRING_HASH, rmw.Qos(depth=7)) == \
        f"@ros2_lv/2/{zid_t}/0/10/MP/%/%/talker/%chatter/{STRING_DDS}/{STRING_HASH}/::,7:,:,:,,"


def test_tokens_and_keys_agree_with_an_independent_client() -> None:
    node = NodeEntity(domain_id=3, session_id="ab12", node_id=4, node_name="bridge",
                      namespace="/viscover")
    ep = EndpointEntity(node=node, entity_id=7, kind=EntityKind.PUBLISHER, name="/viscover/A/pose",
                        dds_type_name=rmw.dds_type_name(ts.POSE_STAMPED),
                        type_hash=ts.rihs01(ts.POSE_STAMPED), qos="::,10:,:,:,,")
    assert rmw.node_token(3, "ab12", 4, "/viscover", "bridge") == \
        sdk_keyexpr.node_liveliness_keyexpr(node)
    assert rmw.entity_token(3, "ab12", 4, 7, rmw.PUBLISHER, "/viscover", "bridge",
                            "/viscover/A/pose", ep.dds_type_name, ep.type_hash,
                            rmw.Qos()) == sdk_keyexpr.endpoint_liveliness_keyexpr(ep)
    assert rmw.data_key(3, "/viscover/A/pose", ep.dds_type_name, ep.type_hash) == \
        sdk_keyexpr.topic_keyexpr(3, "/viscover/A/pose", ep.dds_type_name, ep.type_hash)


def test_qos_string_leaves_rmw_zenoh_defaults_out() -> None:
    assert rmw.qos_keyexpr(rmw.RMW_ZENOH_DEFAULT) == "::,:,:,:,,"
    odd = rmw.Qos(QosReliability.BEST_EFFORT, QosDurability.TRANSIENT_LOCAL,
                  QosHistory.KEEP_ALL, 5)
    assert rmw.qos_keyexpr(odd) == "2:1:2,5:,:,:,,"


def test_attachment_is_33_little_endian_bytes() -> None:
    gid = bytes(range(16))
    att = rmw.encode_attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(att) == rmw.ATTACHMENT_SIZE == 33
    assert struct.unpack("<qqB", att[:17]) == (7, 1_700_000_000_123_456_789, 16)
    assert att[17:] == gid
    assert rmw.decode_attachment(att) == rmw.Attachment(7, 1_700_000_000_123_456_789, gid)
    other = SdkAttachment.from_bytes(att)  # the independent client reads it the same
    assert (other.sequence_id, other.timestamp_ns, other.gid) == (7, 1_700_000_000_123_456_789,
                                                                  gid)
    for bad in (None, b"", att[:20], att + b"x"):
        assert rmw.decode_attachment(bad) is None
    with pytest.raises(ValueError):
        rmw.encode_attachment(1, 2, b"short")


def test_gid_is_xxh3_128_of_the_token_low_half_first() -> None:
    token = "@ros2_lv/0/ab/0/1/MP/%/%/talker/%chatter/x/y/::,:,:,:,,"
    value = xxhash.xxh3_128(token.encode()).intdigest()
    gid = rmw.gid_of(token)
    assert gid[:8] == (value & (2**64 - 1)).to_bytes(8, "little")
    assert gid[8:] == (value >> 64).to_bytes(8, "little")


@pytest.mark.parametrize("typename", ts.TYPES)
def test_type_hashes_agree_with_an_independent_implementation(typename: str) -> None:
    """zenoh-ros2-sdk hashes the .msg text itself (REP-2016): the same RIHS01 as rosbags."""
    main, *deps = ts.msgdef(typename).split("=" * 80 + "\n")
    dependencies = {}
    for d in deps:
        head, _, body = d.partition("\n")
        pkg, _, name = head.removeprefix("MSG: ").partition("/")
        dependencies[f"{pkg}/msg/{name}"] = body
    assert compute_type_hash_from_msg(typename, main, dependencies) == ts.rihs01(typename)


def fields(store: Typestore, typename: str, seen: dict[str, object] | None = None
           ) -> dict[str, object]:
    """The fields of ``typename`` and of every type it uses (what its CDR depends on)."""
    seen = {} if seen is None else seen
    if typename not in seen:
        seen[typename] = flds = store.fielddefs[typename][1]
        for _name, desc in flds:
            for t in re.findall(r"'([a-z0-9_]+/msg/[A-Za-z0-9_]+)'", repr(desc)):
                fields(store, t, seen)
    return seen


@pytest.mark.parametrize("typename", ts.TYPES)
def test_humble_and_jazzy_serialise_the_types_alike(typename: str) -> None:
    """One store serves both conventions: every type used has the same fields, its own and
    its members', in both (only constants differ: Jazzy adds Marker.ARROW_STRIP, Humble types
    Log's level constants as byte; constants are not serialised)."""
    humble, jazzy = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS2_JAZZY)
    assert fields(humble, typename) == fields(jazzy, typename)


# -- names and frames --------------------------------------------------------------------------
def test_drone_ids_become_ros_tokens() -> None:
    assert [drone_token(d) for d in ("A", "cf-1", "7", "a__b")] == ["A", "cf_1", "d7", "a_b"]
    with pytest.raises(ValueError, match="both map"):
        drone_tokens(["a-b", "a_b"])
    assert check_namespace("/lab/viscover") == "/lab/viscover"
    for bad in ("viscover", "/", "/a/", "/9a", "/a__b", "/a-b"):
        with pytest.raises(ValueError):
            check_namespace(bad)


@pytest.mark.parametrize("v", [(1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.6, 0.0, 0.8),
                               (0.36, 0.48, -0.8), (0.0, 0.0, 1.0)])
def test_camera_frame_looks_along_v_with_no_roll(v: tuple[float, float, float]) -> None:
    q = frames.camera_quat(v)
    assert np.allclose(frames.rotate(q, (1.0, 0.0, 0.0)), v, atol=1e-12)
    left = frames.rotate(q, (0.0, 1.0, 0.0))
    assert abs(left[2]) < 1e-12  # y stays horizontal
    body = frames.level_body_quat(v)
    assert abs(frames.rotate(body, (0.0, 0.0, 1.0))[2] - 1.0) < 1e-12  # level body
    rel = frames.camera_in_body(body, v)
    assert np.allclose(frames.multiply(body, rel), q, atol=1e-12) or \
        np.allclose(frames.multiply(body, rel), [-c for c in q], atol=1e-12)


def test_mocap_attitude_and_frustum() -> None:
    w, z = math.cos(0.4), math.sin(0.4)  # yaw 0.8 rad, wire order (w, x, y, z)
    assert np.allclose(frames.mocap_quat((w, 0.0, 0.0, z)), (0.0, 0.0, z, w))
    pts = np.array(frames.frustum_points((1.0, 2.0, 3.0), (0.0, 1.0, 0.0), 2.0,
                                         math.radians(45), math.radians(30)))
    assert pts.shape == (16, 3)
    assert np.allclose(pts[0:8:2], [1.0, 2.0, 3.0])  # the four edges start at the apex
    corners = pts[1:8:2]
    assert np.allclose(corners[:, 1], 4.0)  # 2 m ahead along +y
    assert np.allclose(sorted(set(np.round(corners[:, 0], 9))), [-1.0, 3.0])  # ± tan 45°·2
    assert np.allclose(sorted(set(np.round(corners[:, 2], 9))),
                       [3.0 - 2 * math.tan(math.radians(30)), 3.0 + 2 * math.tan(math.radians(30))])


# -- messages ----------------------------------------------------------------------------------
def hexagon(extra: str = "") -> MissionRos:
    text = scenario_path("hexagon_5_3").read_text() + extra
    return MissionRos(parse_scenario(text, "hexagon"), Names("/viscover"), scene_hz=10.0)


def test_pose_and_tf_decode_to_the_agent_pose() -> None:
    m = hexagon()
    outs = m.pose("B", (1.0, 2.0, 0.5), (0.0, 1.0, 0.0), 5_000_000_123)
    assert [o.topic for o in outs] == ["/viscover/B/pose", "/tf", "/viscover/frusta"]
    pose = decode(outs[0].msg, outs[0].typename, PoseStamped)
    assert (pose.header.stamp.sec, pose.header.stamp.nanosec) == (5, 123)
    assert pose.header.frame_id == "world"
    assert (pose.pose.position.x, pose.pose.position.y, pose.pose.position.z) == (1.0, 2.0, 0.5)
    o = pose.pose.orientation
    assert np.allclose(frames.rotate((o.x, o.y, o.z, o.w), (1, 0, 0)), (0, 1, 0))
    tf = decode(outs[1].msg, outs[1].typename, TFMessage)
    assert [(t.header.frame_id, t.child_frame_id) for t in tf.transforms] == \
        [("world", "B"), ("B", "B/camera")]
    fr = decode(outs[2].msg, outs[2].typename, MarkerArray)
    assert [(mk.ns, mk.id, mk.type) for mk in fr.markers] == [("frustum", 1, 5), ("label", 1, 9)]
    assert len(fr.markers[0].points) == 16
    assert m.pose("B", (1.0, 2.0, 0.5), (0.0, 1.0, 0.0), 5_050_000_000)[-1].topic == "/tf"
    assert m.pose("nobody", (0, 0, 0), (1, 0, 0), 6_000_000_000) == []


def test_mocap_takes_the_body_over_from_the_agent_pose() -> None:
    m = hexagon()
    m.pose("A", (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), 1_000_000_000)
    outs = m.mocap("A", (0.1, 0.2, 1.1), (math.cos(0.3), 0.0, 0.0, math.sin(0.3)), 1_010_000_000)
    assert [o.topic for o in outs] == ["/viscover/A/mocap", "/tf"]
    tf = decode(outs[1].msg, outs[1].typename, TFMessage)
    body, cam = tf.transforms
    assert (body.child_frame_id, body.transform.translation.x) == ("A", 0.1)
    assert np.isclose(body.transform.rotation.z, math.sin(0.3))
    r = cam.transform.rotation  # the camera still looks along world +x
    world = frames.multiply((body.transform.rotation.x, body.transform.rotation.y,
                             body.transform.rotation.z, body.transform.rotation.w),
                            (r.x, r.y, r.z, r.w))
    assert np.allclose(frames.rotate(world, (1, 0, 0)), (1, 0, 0), atol=1e-9)
    # fresh mocap: the agent pose no longer moves the body on /tf
    assert [o.topic for o in m.pose("A", (0, 0, 1), (1, 0, 0), 1_050_000_000)] == \
        ["/viscover/A/pose"]
    assert "/tf" in [o.topic for o in m.pose("A", (0, 0, 1), (1, 0, 0), 2_000_000_000)]


def test_landmarks_are_coloured_by_owner_and_sent_on_change() -> None:
    m = hexagon()
    owner = np.array([0, 0, 1, -1, 2, 2], dtype=np.intp)  # rows of ["A", "B", "C"]
    outs = m.ownership(["A", "B", "C"], owner, 7_000_000_000)
    arr = decode(outs[0].msg, outs[0].typename, MarkerArray)
    mk = arr.markers[0]
    assert (mk.ns, mk.type, mk.header.frame_id) == ("landmarks", 7, "world")
    assert np.allclose([[p.x, p.y, p.z] for p in mk.points], m.q)
    cols = [(c.r, c.g, c.b) for c in mk.colors]
    assert np.allclose(cols[0], messages.drone_rgba(0)[:3], atol=1e-6)
    assert np.allclose(cols[3], messages.UNOWNED_RGBA[:3], atol=1e-6)
    assert np.allclose(cols[4], messages.drone_rgba(2)[:3], atol=1e-6)
    assert m.ownership(["A", "B", "C"], owner, 7_100_000_000) == []  # unchanged
    assert len(m.ownership(["A", "B", "C"], owner, 7_200_000_000, force=True)) == 1
    # rows of another order map onto the bridge's own rows
    again = m.ownership(["C", "A", "B"], np.array([1, 1, 2, -1, 0, 0]), 7_300_000_000,
                        force=True)
    recoloured = decode(again[0].msg, again[0].typename, MarkerArray)
    assert np.allclose([(c.r, c.g, c.b) for c in recoloured.markers[0].colors], cols, atol=1e-6)


def test_inspection_capture_log_and_map() -> None:
    m = hexagon("\n[inspection]\nquality = 0.3\n")
    bits = pack_bits(np.array([True, False, True, False, False, False]))
    outs = m.state("A", "optimising", 2, 0.4, bits, 8_000_000_000)
    assert [o.topic for o in outs] == ["/viscover/events", "/viscover/captures"]
    log = decode(outs[0].msg, outs[0].typename, Log)
    assert (log.name, log.function, log.level) == ("viscover.A", "capture", 20)
    assert "2 new capture(s) (landmarks 1, 3); 2 / 6 captured" in log.msg
    captures = decode(outs[1].msg, outs[1].typename, MarkerArray)
    cols = [(c.r, c.g) for c in captures.markers[0].colors]
    assert np.allclose(cols[0], messages.CAPTURED_RGBA[:2], atol=1e-6)
    assert np.allclose(cols[1], messages.PENDING_RGBA[:2], atol=1e-6)
    assert m.state("B", "optimising", 2, 0.4, bits, 8_100_000_000) == []  # nothing new


def test_one_drone_claiming_every_landmark_does_not_colour_the_map() -> None:
    m = hexagon("\n[inspection]\nquality = 0.3\n")
    first = pack_bits(np.array([True, False, False, False, False, False]))
    m.state("A", "optimising", 2, 0.4, first, 8_000_000_000)
    m.state("B", "optimising", 2, 0.4, first, 8_100_000_000)
    # C's word alone (1 vote of 3) makes nothing captured: nothing new is logged or drawn
    assert m.state("C", "optimising", 2, 0.4, pack_bits(np.ones(6, dtype=np.bool_)),
                   8_200_000_000) == []
    outs = m.state("B", "optimising", 2, 0.4, pack_bits(np.array([True, True, False, False,
                                                                   False, False])),
                   8_300_000_000)  # B agrees with C on landmark 2: 2 votes of 3
    log = decode(outs[0].msg, outs[0].typename, Log)
    assert "B: 1 new capture(s) (landmarks 2); 2 / 6 captured" in log.msg


def test_status_and_events() -> None:
    m = hexagon()
    rows = [DroneRow("A", "converged", 2, 0.5, "1 / 0", "ok", "0.1 s ago", "-", "-", True),
            DroneRow("B", "-", 0, 0.0, "-", "stale", "4.0 s ago", "-", "-", False)]
    view = MissionView(mission="hexagon_5_3", rows=rows, coverage=0.75, seen=4, not_seen=1,
                       unowned=1, elapsed_s=12.0, mission_t=11.5, complete=False,
                       violations=[], rejected=0)
    out = m.status(view, 9_000_000_000)
    arr = decode(out.msg, out.typename, DiagnosticArray)
    assert [(s.name, s.level, s.hardware_id) for s in arr.status] == [
        ("viscover/A", 0, "A"), ("viscover/B", 3, "B"), ("viscover/mission", 1, "hexagon_5_3")]
    values = {kv.key: kv.value for kv in arr.status[2].values}
    assert (values["coverage"], values["unowned"]) == ("0.75", "1")
    ev = PhaseChange(time=12.5, source="B", level="warning", text="B: x", phase="landing",
                     previous="converged")
    log = decode(m.event(ev, 0).msg, ts.LOG, Log)
    assert (log.stamp.sec, log.stamp.nanosec, log.level, log.msg) == (12, 500_000_000, 30, "B: x")
    assert (log.name, log.function) == ("viscover.B", "phase")


def test_command_targets() -> None:
    known = ["A", "cf-1"]
    assert messages.parse_targets("", known) == (None, [])
    assert messages.parse_targets(" all ", known) == (None, [])
    assert messages.parse_targets("A, cf_1 cf-1 Z", known) == (["A", "cf-1"], ["Z"])
