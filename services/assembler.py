"""Scan assembly: scan/** (any message affordwire.sensors decodes) in; map/pose per frame and map/cloud
(rate-limited, and once more when the scans stop) out. Registration and the global map are
affordcore.assembly's."""

from __future__ import annotations

import time

import numpy as np

from affordcore.assembly import Assembler
from affordcore.recording import log_cloud, log_scan, log_trajectory, set_time
from affordwire import messages
from affordwire.sensors import decode_sensor

from .node import Inbound, Inbox, Node

# seconds without scans after which a pending map goes out whatever the rate limit
QUIET_BEFORE_PUBLISHING = 0.5


class AssemblerService:
    def __init__(self, node: Node):
        self.node = node
        self.settings = node.settings.assembler
        self.assembler = Assembler(self.settings)
        self.inbox = Inbox(latest_only=False, limit=node.settings.service.max_queue)
        self.last_published = -np.inf
        self.last_scan = 0.0
        self.pending = False  # frames registered since the last published map
        self.last_stamp = 0.0
        node.subscribe(node.keys.scans, self.inbox)
        for key in (node.keys.cloud, node.keys.pose):
            node.answer_latest(key)

    def run(self) -> None:
        self.node.run(self.inbox, self.handle, self.idle)

    def handle(self, item: Inbound) -> None:
        frame = decode_sensor(item.schema, item.payload)
        at = frame.stamp or item.arrived
        pose = self.assembler.add(frame, at)
        self.last_scan, self.pending, self.last_stamp = time.monotonic(), True, at

        pose_message = messages.Pose()
        messages.set_pose(pose_message, pose, "odom", frame.frame_id, at)
        self.node.publish(self.node.keys.pose, pose_message)
        set_time(self.node.recording, at)
        log_scan(self.node.recording, self.assembler.registered_points, pose)
        if time.monotonic() - self.last_published >= self.settings.publish_period:
            self.publish_map()

    def idle(self) -> None:
        if self.pending and time.monotonic() - self.last_scan >= QUIET_BEFORE_PUBLISHING:
            self.publish_map()

    def publish_map(self) -> None:
        """Align the global map to gravity and publish it; until a floor is in view, there is nothing to
        send."""
        try:
            points, world_from_odom = self.assembler.aligned_map(self.node.settings)
        except ValueError as error:
            self.node.publish_status(
                messages.Status.READY, f"{self.assembler.frames} frames, no map yet: {error}"
            )
            self.last_published = time.monotonic()
            self.pending = False
            return
        cloud = messages.cloud_message(
            points, world_from_odom, self.node.service, self.assembler.frames, self.last_stamp
        )
        self.node.publish(self.node.keys.cloud, cloud)
        self.last_published, self.pending = time.monotonic(), False
        set_time(self.node.recording, self.last_stamp)
        log_trajectory(self.node.recording, self.assembler.trajectory.positions, world_from_odom)
        log_cloud(self.node.recording, points)
        self.node.publish_status(
            messages.Status.READY,
            f"published the map of {self.assembler.frames} frames, {len(points):,} points",
        )
