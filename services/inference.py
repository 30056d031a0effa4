"""Model inference: fields in, affordance/<name> out, one AffordanceMap per model (the shipped models unless
others are configured). Scoring and maps are affordcore.pipeline's `map_affordances`."""

from __future__ import annotations

from affordcore.features import FeatureLayout
from affordcore.pipeline import map_affordances
from affordcore.recording import log_map, set_time
from affordwire import messages

from .node import Inbound, Node


class InferenceService:
    def __init__(self, node: Node):
        self.node, self.models = node, node.models
        self.layout = FeatureLayout.from_settings(node.settings.features, node.settings.voxel)
        self.inbox = node.inbox(latest_only=True)
        node.subscribe(node.keys.fields, self.inbox)
        for model in self.models:
            node.answer_latest(node.keys.affordance(model.affordance))
        node.fetch_latest(node.keys.fields, self.inbox)  # fields published before this service (re)started

    def run(self) -> None:
        self.node.run(self.inbox, self.handle)

    def handle(self, item: Inbound) -> None:
        message = self.node.decode(item, messages.SceneFieldsMessage)
        settings = self.node.settings
        fields = messages.scene_fields(message, settings.limits, settings.voxel.max_voxels)
        if abs(fields.lattice.resolution - self.node.settings.voxel.resolution) > 1e-9:
            raise messages.MessageError(
                f"fields at {fields.lattice.resolution} m voxels; the models here need "
                f"{self.node.settings.voxel.resolution} m (AFFORD_VOXEL__RESOLUTION of the features service)"
            )
        self.node.publish_status(messages.Status.BUSY, f"mapping {len(self.models)} affordances")
        set_time(self.node.recording, messages.seconds(message.cloud_timestamp))
        ids = {model.affordance: model.id for model in self.models}

        def publish(affordance: str, amap) -> None:
            self.node.publish(
                self.node.keys.affordance(affordance), messages.map_message(amap, ids[affordance], message)
            )
            log_map(self.node.recording, amap)

        map_affordances(fields, self.layout, self.models, self.node.settings, on_map=publish)
        self.node.publish_status(
            messages.Status.READY, f"published {len(self.models)} maps of a {message.frames}-frame map"
        )
