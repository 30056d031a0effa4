"""Feature extraction: map/cloud in, fields out (occupancy, distance transform and normals of the room, which
every affordance's scores are read from), by affordcore.pipeline's one path from a cloud to its fields."""

from __future__ import annotations

from affordcore.pipeline import prepare_scene
from affordcore.recording import log_cloud, log_fields, set_time
from affordcore.scene import Cloud
from affordwire import messages

from .node import Inbound, Node


class FeaturesService:
    def __init__(self, node: Node):
        self.node = node
        self.inbox = node.inbox(latest_only=True)  # a newer map supersedes one not yet worked on
        node.subscribe(node.keys.cloud, self.inbox)
        node.answer_latest(node.keys.fields)
        node.fetch_latest(node.keys.cloud, self.inbox)  # a map published before this service (re)started

    def run(self) -> None:
        self.node.run(self.inbox, self.handle)

    def handle(self, item: Inbound) -> None:
        cloud = self.node.decode(item, messages.CloudMessage)
        points = messages.cloud_points(cloud, self.node.settings.limits)
        self.node.publish_status(messages.Status.BUSY, f"computing the fields of {len(points):,} points")
        # map clouds arrive in the world frame (cloud_points checked it): no alignment here
        scene = prepare_scene(Cloud(points, source=item.key), self.node.settings, gravity="none")
        message = messages.fields_message(scene.fields, cloud)
        self.node.publish(self.node.keys.fields, message)
        set_time(self.node.recording, messages.seconds(cloud.timestamp))
        log_cloud(self.node.recording, scene.cloud.points)
        log_fields(self.node.recording, scene.fields)
        self.node.publish_status(
            messages.Status.READY,
            f"published fields {scene.fields.lattice.shape} of a {cloud.frames}-frame map",
        )
