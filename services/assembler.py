"""Scan assembly: scan/** (Scan or DepthFrame) in; map/pose per frame and map/cloud (rate-limited, and once
more when the scans stop) out. The registration and the global map are affordcore.assembly's."""

from __future__ import annotations

import time

import numpy as np

from affordcore import messages
from affordcore.assembly import Assembler, depth_block_points
from affordcore.recording import log_cloud, log_scan, log_trajectory, set_time

from .node import Inbound, Inbox, Node

SERVICE = "assembler"
QUIET_BEFORE_PUBLISHING = 0.5  # seconds without scans after which a pending map goes out whatever the rate limit


class AssemblerService:
    def __init__(self, node: Node):
        self.node = node
        self.settings = node.settings.assembler
        self.assembler = Assembler(self.settings)
        self.inbox = Inbox(latest_only=False, limit=node.settings.service.max_queue)
        self.last_published = -np.inf
        self.last_scan = 0.0
        self.pending = False  # frames registered since the last published map
        self.last_stamp = None
        node.subscribe(node.keys.scans, self.inbox)
        for key in (node.keys.cloud, node.keys.pose):
            node.answer_latest(key)

    def run(self) -> None:
        self.node.run(self.inbox, self.handle, self.idle)

    def handle(self, item: Inbound) -> None:
        message = self.node.decode(item, messages.Scan, messages.DepthFrame)
        points = self._points(message)
        guess = messages.pose_matrix(message.pose_guess) if message.HasField("pose_guess") else None
        at = messages.seconds(message.timestamp) or item.arrived
        pose = self.assembler.register(points, at, guess, messages.gravity_of(message))
        self.last_scan, self.pending, self.last_stamp = time.monotonic(), True, message.timestamp

        pose_message = messages.Pose()
        messages.set_pose(pose_message, pose, "odom", message.frame_id or "sensor", at)
        self.node.publish(self.node.keys.pose, pose_message)
        set_time(self.node.recording, at)
        log_scan(self.node.recording, self.assembler.registered_points, pose)
        if time.monotonic() - self.last_published >= self.settings.publish_period:
            self.publish_map()

    def _points(self, message) -> np.ndarray:
        if isinstance(message, messages.DepthFrame):  # block means: 3.7 / 7.0 cm against 4.5 / 10.5 on the real kitchen
            image, intrinsics = messages.depth_image(message)
            return depth_block_points(image, intrinsics, self.settings.pixel_step, self.settings.min_range,
                                      self.settings.max_range, message.depth_scale, message.invalid_value)
        points, _ = messages.unpack_points(message)
        return points

    def idle(self) -> None:
        if self.pending and time.monotonic() - self.last_scan >= QUIET_BEFORE_PUBLISHING:
            self.publish_map()

    def publish_map(self) -> None:
        """Align the global map to gravity and publish it; until a floor is in view there is nothing to send."""
        try:
            points, world_from_odom = self.assembler.aligned_map(self.node.settings.gravity)
        except ValueError as error:
            self.node.publish_status(messages.Status.READY, f"{self.assembler.frames} frames, no map yet: {error}")
            self.last_published = time.monotonic()
            self.pending = False
            return
        at = messages.seconds(self.last_stamp)
        cloud = messages.cloud_message(points, world_from_odom, SERVICE, self.assembler.frames, at)
        self.node.publish(self.node.keys.cloud, cloud)
        self.last_published, self.pending = time.monotonic(), False
        set_time(self.node.recording, at)
        log_trajectory(self.node.recording, self.assembler.trajectory.positions, world_from_odom)
        log_cloud(self.node.recording, points)
        self.node.publish_status(messages.Status.READY, f"published the map of {self.assembler.frames} frames, {len(points):,} points")
