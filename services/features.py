"""Feature extraction: map/cloud in, fields out (occupancy, distance transform and normals of the room, which
every affordance's scores are read from). The fields are affordcore.fields'."""

from __future__ import annotations

from affordcore import messages
from affordcore.fields import compute_fields
from affordcore.recording import log_cloud, log_fields, set_time

from .node import Inbound, Inbox, Node

SERVICE = "features"


class FeaturesService:
    def __init__(self, node: Node):
        self.node = node
        self.inbox = Inbox(latest_only=True, limit=1)  # a newer map supersedes one not yet worked on
        node.subscribe(node.keys.cloud, self.inbox)
        node.answer_latest(node.keys.fields)

    def run(self) -> None:
        self.node.run(self.inbox, self.handle)

    def handle(self, item: Inbound) -> None:
        cloud = self.node.decode(item, messages.Cloud)
        points = messages.cloud_points(cloud)
        self.node.publish_status(messages.Status.BUSY, f"computing the fields of {len(points):,} points")
        settings = self.node.settings
        fields = compute_fields(points, settings.voxel, settings.normals)
        message = messages.fields_message(fields, cloud)
        self.node.publish(self.node.keys.fields, message)
        set_time(self.node.recording, messages.seconds(cloud.timestamp))
        log_cloud(self.node.recording, points)
        log_fields(self.node.recording, fields)
        self.node.publish_status(messages.Status.READY, f"published fields {fields.lattice.shape} of a {cloud.frames}-frame map")
