"""The recording's FrameTransforms (``/drones/<id>/tf``, ``/drones/<id>/camera_tf``):
decoded from the MCAP with google.protobuf and the file's own schema, their frames and
values checked against the poses that were published, with a quaternion rotation written
here (not the recorder's).

Conventions under test: ``world`` → ``drone/<id>`` translates to the pose's position and
turns x onto the camera's horizontal heading with z up; ``drone/<id>`` → ``drone/<id>/camera``
is the optical frame: +z the camera direction v, +x the image's right (horizontal, v × ẑ),
+y down the image.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from agent.config.parse import load_scenario
from agent.mission.recorder import Recorder
from agent.net.memory import MemoryNetwork
from agent.storage import recording as fmt
from agent.wire import keys
from agent.wire.peer import Pose
from tests.conftest import scenario_path
from tests.test_live_view import protobuf_decoder
from tests.test_status_identity import PUB

#: camera directions: level, pitched down, straight down, pitched up
V = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, -0.8], [0.0, 0.0, -1.0], [-0.6, -0.48, 0.64]])
P = np.array([[1.0, 2.0, 3.0], [-1.5, 0.25, 1.0], [0.0, 0.0, 2.5], [0.5, -1.0, 0.75]])


def matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _frames(path: Path) -> dict[str, list[Any]]:
    """The decoded FrameTransforms of each frame topic, in order (protobuf messages of a class
    built at run time from the file's schema: untyped)."""
    out: dict[str, list[Any]] = {}
    with path.open("rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=True):
            if schema is not None and schema.name == "foxglove.FrameTransform":
                decode = protobuf_decoder(schema.name, schema.data)
                out.setdefault(channel.topic, []).append(decode(msg.data))
    return out


def test_the_recording_has_world_drone_camera_frames(tmp_path: Path) -> None:
    net = MemoryNetwork()
    rec = Recorder(net.transport("rec"), load_scenario(str(scenario_path("cube_6_2"))), "m",
                   tmp_path, pose_hz=1e6, scene_hz=1e6)
    tp = net.transport("A")
    for k, (p, v) in enumerate(zip(P, V, strict=True)):
        tp.publish(keys.pose_key("m", "A"), PUB.encode(Pose(
            sender="A", seq=k, t=0.1 * k, p=tuple(p.tolist()), v=tuple(v.tolist()))))
    rec.close()
    frames = _frames(tmp_path / fmt.MCAP_NAME)
    body, cam = frames[fmt.frame_topic("A")], frames[fmt.camera_frame_topic("A")]
    assert len(body) == len(cam) == len(P)
    assert not {fmt.frame_topic("B"), fmt.camera_frame_topic("B")} & set(frames)  # B never flew
    for p, v, b, c in zip(P, V, body, cam, strict=True):
        assert (b.parent_frame_id, b.child_frame_id) == ("world", "drone/A")
        assert (c.parent_frame_id, c.child_frame_id) == ("drone/A", "drone/A/camera")
        assert [b.translation.x, b.translation.y, b.translation.z] == pytest.approx(p)
        assert [c.translation.x, c.translation.y, c.translation.z] == [0.0, 0.0, 0.0]
        rb = matrix(np.array([b.rotation.x, b.rotation.y, b.rotation.z, b.rotation.w]))
        rc = matrix(np.array([c.rotation.x, c.rotation.y, c.rotation.z, c.rotation.w]))
        # the drone frame: level (z up), x along the camera's heading when it has one
        np.testing.assert_allclose(rb[:, 2], [0.0, 0.0, 1.0], atol=1e-9)
        heading = np.array([v[0], v[1], 0.0])
        if np.linalg.norm(heading) > 1e-9:
            np.testing.assert_allclose(rb[:, 0], heading / np.linalg.norm(heading), atol=1e-9)
        # the camera's optical frame in the world
        world = rb @ rc
        right = np.cross(v, [0.0, 0.0, 1.0])
        right = right / np.linalg.norm(right) if np.linalg.norm(right) > 1e-9 else \
            np.array([1.0, 0.0, 0.0])
        np.testing.assert_allclose(world[:, 2], v, atol=1e-9)  # optical axis
        np.testing.assert_allclose(world[:, 0], right, atol=1e-9)  # image right
        np.testing.assert_allclose(world[:, 1], np.cross(v, right), atol=1e-9)  # image down
        assert world[2, 0] == pytest.approx(0.0, abs=1e-9)  # no roll: the right is level
        # a point 2 m ahead of the camera is 2 m along v from the drone, in the world
        ahead = rb @ (rc @ np.array([0.0, 0.0, 2.0])) + p
        np.testing.assert_allclose(ahead, p + 2.0 * v, atol=1e-9)
