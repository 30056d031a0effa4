"""Scan assembly: scan/** (any message affordwire.sensors decodes) in; map/pose per frame and map/cloud
(rate-limited, and once more when the scans stop) out. Registration and the global map are
affordcore.assembly.assembler's; with a state folder (`--state`) every accepted frame is journaled before its
pose goes
out, and the map checkpointed, by affordcore.assembly.checkpoint."""

from __future__ import annotations

import time

import numpy as np

from affordcore.assembly.assembler import Assembler
from affordcore.assembly.checkpoint import AssemblerStore
from affordcore.mapping.recording import log_cloud, log_scan, log_trajectory, set_time
from affordwire import messages
from affordwire.sensors import decode_sensor

from .node import Inbound, Node
from .ros import RosInput
from .ros_maps import WorldInTf

# seconds without scans after which a pending map goes out whatever the rate limit
QUIET_BEFORE_PUBLISHING = 0.5


class AssemblerService:
    def __init__(self, node: Node):
        self.node = node
        self.settings, self.limits = node.settings.assembler, node.settings.limits
        self.assembler = Assembler(self.settings, self.limits)
        state = node.settings.service.state
        self.store = None if state is None else AssemblerStore(state)
        restored = self.store.restore(self.assembler) if self.store else 0
        self.last_checkpoint = time.monotonic()
        self.last_published = -np.inf  # the last map that went out
        self.last_attempt = -np.inf  # ... or that did not, for want of a floor
        self.first_scan: float | None = None  # when this run's first scan was taken
        self.last_scan = 0.0
        self.pending = restored > 0  # frames registered since the last published map
        self.behind = False  # a scan found others waiting since the last published map
        self.last_stamp = self.assembler.trajectory.stamps[-1] if restored else 0.0
        if self.store:
            print(f"[assembler] restored {restored} frames from {self.store.folder}", flush=True)
        self.inbox = node.inbox(latest_only=False, skip_when_late=True)
        self.inbox.check = self._check  # a scan is decoded on arrival: a bad one never waits in line
        node.subscribe(node.keys.scans, self.inbox)
        # ROS 2 clouds (and Imu gravity) too, when AFFORD_ROS__POINTS names a topic (services/ros.py)
        self.ros = RosInput(node, self.inbox) if RosInput.wanted(node.settings.ros) else None
        # afford's world in the robot's tf, when the maps go out on ROS 2 and the odometry ties the frames
        self.world_tf = None
        if self.ros is not None and WorldInTf.wanted(node.settings.ros):
            self.world_tf = WorldInTf(node, self.ros)
        for key in (node.keys.cloud, node.keys.pose):
            node.answer_latest(key)
        node.on_reset = self.forget

    def forget(self) -> None:
        """At an operator's reset: a new map, no trajectory, an empty state folder."""
        self.assembler = Assembler(self.settings, self.limits)
        if self.store:
            self.store.clear()
        self.last_published = self.last_attempt = -np.inf
        self.first_scan, self.last_scan, self.last_stamp = None, 0.0, 0.0
        self.pending = self.behind = False

    def run(self) -> None:
        try:
            self.node.run(self.inbox, self.handle, self.idle, self.stop)
        finally:
            if self.ros is not None:
                print(f"[assembler] {self.ros.summary()}", flush=True)

    def _check(self, item: Inbound, parsed) -> object:
        """On arrival: the sensor frame a scan holds (a ROS 2 cloud: its decoded points), checked."""
        if self.ros is not None and self.ros.takes(item):
            return self.ros.decode(item)
        return decode_sensor(item.schema, item.payload, self.limits)

    def handle(self, item: Inbound) -> None:
        if self.ros is not None and self.ros.takes(item):
            frame = self.ros.frame(item, item.checked)
        else:
            frame = item.checked
        at = frame.stamp or item.arrived
        # a scan refused from here on (a pose jump, ...) changes no map, but the next map says it was
        # received: afford watch waits for the map that covers the last scan published, whatever became of
        # it (a message refused on arrival, undecodable, is no scan: it is not counted)
        self.pending = True
        # with scans waiting, a cheaper registration: more frames taken, fewer skipped to keep up
        busy = len(self.inbox) > 0
        record = self.assembler.add(frame, at, busy)  # a refused frame raises here and changes nothing
        if self.ros is not None:
            self.ros.tie(record.pose, frame.pose_guess)
        self.node.no_output = ""  # the map has changed: whether it makes one is not known until the next try
        if self.store:
            self.store.append(record)  # before anything goes out about it
        if record.note:
            print(f"[assembler] frame at {at:.3f} s: {record.note}", flush=True)
        pose = record.pose
        self.last_scan, self.pending, self.last_stamp = time.monotonic(), True, at
        self.first_scan = self.first_scan or self.last_scan

        pose_message = messages.Pose()
        messages.set_pose(pose_message, pose, "odom", frame.frame_id, at)
        self.node.publish(self.node.keys.pose, pose_message)
        set_time(self.node.recording, at)
        log_scan(self.node.recording, self.assembler.registered_points, pose)
        self.behind = self.behind or busy
        if self.map_due():
            self.publish_map()

    def map_due(self) -> bool:
        """Every publish_period; behind the sensor, every busy_publish_period: features and inference then
        leave the cores to the assembler, and have less stale work in hand when the scans stop and the last
        map comes. Both count from the first scan too (a map of a frame or two is worth nobody's work). A map
        not sent for want of a floor cost them nothing: the next try is not held back."""
        now, settings = time.monotonic(), self.settings
        if now - max(self.last_attempt, self.first_scan) < settings.publish_period:
            return False
        since = max(self.last_published, self.first_scan)
        return not self.behind or now - since >= settings.busy_publish_period

    def idle(self) -> None:
        if self.pending and time.monotonic() - self.last_scan >= QUIET_BEFORE_PUBLISHING:
            self.publish_map()
        if self.store and time.monotonic() - self.last_checkpoint >= self.settings.checkpoint_period:
            self.store.snapshot(self.assembler)
            self.last_checkpoint = time.monotonic()

    def stop(self) -> str:
        """At SIGTERM: checkpoint the map, so a restart takes up where this run stopped."""
        if self.store is None:
            return f"no state folder (--state): the map of {self.assembler.frames} frames is not kept"
        self.store.snapshot(self.assembler)
        self.store.close()
        return f"checkpointed the map of {self.assembler.frames} frames to {self.store.folder}"

    def publish_map(self) -> None:
        """Align the global map to gravity and publish it; until a floor is in view, there is nothing to
        send."""
        try:
            points, world_from_odom = self.assembler.aligned_map(self.node.settings)
        except ValueError as error:
            self.node.no_output = f"{self.assembler.frames} frames, no map yet: {error}"
            self.node.publish_status(messages.Status.READY, self.node.no_output)
            self.last_attempt = time.monotonic()
            self.pending = False
            return
        if self.store:
            self.store.save_alignment(world_from_odom)  # the world frame survives a restart as it is
        cloud = messages.cloud_message(
            points,
            world_from_odom,
            self.node.service,
            self.assembler.frames,
            self.last_stamp,
            scans_received=self.inbox.settled(),
            origins=self.assembler.sensor_origins(world_from_odom, self.node.settings.visibility.max_origins),
        )
        self.node.publish(self.node.keys.cloud, cloud)
        if self.world_tf is not None:
            self.world_tf.publish(world_from_odom, self.last_stamp)
        self.last_published = self.last_attempt = time.monotonic()
        self.pending, self.behind = False, False
        set_time(self.node.recording, self.last_stamp)
        log_trajectory(self.node.recording, self.assembler.trajectory.positions, world_from_odom)
        log_cloud(self.node.recording, points)
        kept = self.assembler.levelling_kept
        self.node.publish_status(
            messages.Status.READY,
            f"published the map of {self.assembler.frames} frames, {len(points):,} points"
            + (f", levelled as the last map (its own floor search failed: {kept})" if kept else ""),
        )
