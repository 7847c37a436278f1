"""Field flights: the clients a flying agent opens on its driver's link for an outdoor
inspection, together, and closed together (an :class:`~contextlib.ExitStack`).

* pose from the autopilot (``pose = "autopilot"``): :class:`~agent.flight.autopilot_pose.
  AutopilotPose` replaces the mocap feed as the stream's pose provider; nothing is forwarded
  to the EKF (it is the EKF's own estimate);
* camera (:class:`~agent.flight.camera.CameraClient`), discovered at open;
* gimbal (:class:`~agent.flight.gimbal.GimbalClient`), discovered at open (simulated tilt
  when there is none);
* fence (:class:`~agent.flight.fence.FenceClient` installs a :class:`~agent.flight.fence.
  FencePlan`, then the stream flies within its box; :class:`~agent.flight.fence.
  FenceMonitor` reports breaches);
* battery (:class:`~agent.flight.battery.BatteryReader`), always.

Open it after ``driver.start()`` and ``wait_heartbeat()``, before ``engage()``.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from agent.flight.autopilot_pose import AutopilotPose
from agent.flight.battery import BatteryReader
from agent.flight.camera import CameraClient, CameraConfig
from agent.flight.fence import FenceBreach, FenceClient, FenceMonitor, FencePlan
from agent.flight.geodetic import Origin
from agent.flight.gimbal import GimbalClient, GimbalConfig
from agent.flight.mavlink_driver import MavlinkDriver

_log = logging.getLogger(f"viscover.{__name__}")

PoseSourceName = Literal["mocap", "autopilot"]


@dataclass(frozen=True)
class FieldOptions:
    """What to open: the pose source, the mission's geodetic origin (shared by all drones;
    None: each vehicle's EKF frame is the world frame), camera, gimbal, the fence to install
    (None: none) and the time to wait for the autopilot's origin and first pose [s sim]."""

    pose: PoseSourceName = "mocap"
    origin: Origin | None = None
    camera: bool = True
    gimbal: bool = True
    fence: FencePlan | None = None
    camera_config: CameraConfig | None = None
    gimbal_config: GimbalConfig | None = None
    pose_timeout_s: float = 10.0


def use_autopilot_pose(driver: MavlinkDriver, origin: Origin | None,
                       timeout_s: float = 10.0) -> AutopilotPose:
    """Make ``driver`` fly on the autopilot's own estimate (forwarding off, staleness on the
    driver's clock); waits until it is placeable in the world frame (FlightError if not)."""
    pose = AutopilotPose(driver.link, origin, on_pose=driver.notify_pose)
    try:
        pose.wait_ready(timeout_s)
    except BaseException:
        pose.close()
        raise
    if driver.cfg.forward != "none":
        _log.info("pose from the autopilot: not forwarding poses to its EKF")
        driver.cfg.forward = "none"
    driver.streamer.use_pose(pose, "autopilot pose")
    return pose


class FieldClients:
    """The field clients of one driver (see the module docstring); ``close()`` closes all."""

    def __init__(self, driver: MavlinkDriver, options: FieldOptions | None = None,
                 on_breach: Callable[[FenceBreach], None] | None = None) -> None:
        opts = options or FieldOptions()
        self.driver = driver
        self.options = opts
        self.pose: AutopilotPose | None = None
        self.camera: CameraClient | None = None
        self.gimbal: GimbalClient | None = None
        link = driver.link
        with contextlib.ExitStack() as stack:
            self.battery = BatteryReader(link)
            stack.callback(self.battery.close)
            self.fence_monitor = FenceMonitor(link, on_breach)
            stack.callback(self.fence_monitor.close)
            if opts.pose == "autopilot":
                self.pose = use_autopilot_pose(driver, opts.origin, opts.pose_timeout_s)
                stack.callback(self.pose.close)
            if opts.fence is not None:
                fence = FenceClient(link, driver.params)
                stack.callback(fence.close)
                home = self.pose.home_world if self.pose is not None else None
                fence.install(opts.fence, float(home[2]) if home is not None else 0.0)
                driver.streamer.set_space(opts.fence.lo, opts.fence.hi)
            if opts.camera:
                self.camera = CameraClient(link, opts.camera_config, opts.origin)
                stack.callback(self.camera.close)
                self.camera.discover()
            if opts.gimbal:
                self.gimbal = GimbalClient(link, opts.gimbal_config)
                stack.callback(self.gimbal.close)
                self.gimbal.discover()
            self._stack = stack.pop_all()

    def close(self) -> None:
        """Close every client (the driver stays open)."""
        self._stack.close()

    def __enter__(self) -> FieldClients:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
