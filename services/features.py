"""Feature extraction: map/cloud in, fields out (occupancy, distance transform and normals of the room, which
every affordance's scores are read from), by affordcore.mapping.pipeline's one path from a cloud to its
fields. A
cloud in the world frame must be levelled already (checked); one in any other frame is levelled here, by the
same alignment `afford map` uses, and its fields carry the world_from_input that did it. No floor: refused
on error/features, never answered with empty maps."""

from __future__ import annotations

import copy
from concurrent.futures import ThreadPoolExecutor

from affordcore.geometry.gravity import check_levelled
from affordcore.geometry.scene import Cloud
from affordcore.mapping.pipeline import preload, prepare_scene
from affordcore.mapping.recording import log_fields, set_time
from affordcore.mapping.updates import NormalCache
from affordwire import messages

from .node import Inbound, Node


class FeaturesService:
    def __init__(self, node: Node):
        self.node = node
        self.normals = NormalCache()  # the robot's map comes again and again: estimate only what changed
        self.checks = ThreadPoolExecutor(1, thread_name_prefix="levelling-check")
        preload()  # now, not when the first map arrives
        self.inbox = node.inbox(latest_only=True)  # a newer map supersedes one not yet worked on ...
        self.inbox.check = self._check  # ... once it is found sound
        self.held_back, self.held_back_last = 0, False  # fields of superseded maps not published
        node.subscribe(node.keys.cloud, self.inbox)
        node.answer_latest(node.keys.fields)
        node.fetch_latest(node.keys.cloud, self.inbox)  # a map published before this service (re)started
        node.on_reset = self.forget

    def forget(self) -> None:
        """At an operator's reset: no normals of the old room are kept."""
        self.normals = NormalCache()
        self.held_back_last = False

    def run(self) -> None:
        self.node.run(
            self.inbox,
            self.handle,
            on_stop=lambda: f"fields held back, their map superseded while computed: {self.held_back}",
        )

    def _check(self, item: Inbound, parsed) -> tuple:
        """On arrival: the cloud, its points and sensor origins, checked against the limits."""
        cloud = self.node.decode(item, messages.CloudMessage, parsed=parsed)
        limits = self.node.settings.limits
        return cloud, messages.cloud_points(cloud, limits), messages.cloud_origins(cloud, limits)

    def handle(self, item: Inbound) -> None:
        cloud, points, origins = item.checked
        settings = self.node.settings
        levelled = messages.is_levelled(cloud)
        what = (
            "computing the fields"
            if levelled
            else f"levelling (frame {cloud.frame_id or 'unnamed'!r}) and computing the fields"
        )
        self.node.publish_status(messages.Status.BUSY, f"{what} of {len(points):,} points")
        # A levelled cloud's check runs beside its fields (0.1 s of a 0.3 s step, mostly GIL-free numpy) and
        # the fields are made with a copy of the normals, kept only once the check has passed: a refused
        # cloud leaves nothing of itself behind.
        check = self.checks.submit(check_levelled, points, settings.gravity) if levelled else None
        before = self.normals
        normals = copy.copy(before)
        try:
            scene = prepare_scene(
                Cloud(points, source=item.key, origins=origins),
                settings,
                gravity="none" if levelled else "auto",
                normals=normals,
            )
        finally:
            if check is not None:
                check.result()  # NoFloorError: refused, with what is wrong
        if self.normals is before:  # not reset meanwhile
            self.normals = normals
        if self._superseded():
            self.inbox.set_aside(item)  # back to work if the newer map is refused
            self.held_back, self.held_back_last = self.held_back + 1, True
            self.node.publish_status(
                messages.Status.READY,
                f"held back the fields of a {cloud.frames}-frame map: a newer map waits ({self.held_back} "
                "in all; its normals are kept for the next)",
            )
            return
        self.held_back_last = False
        # the Cloud's own world_from_input takes its source to the cloud's frame; levelling goes on from there
        world_from_input = scene.alignment.world_from_input @ messages.pose_matrix(cloud.world_from_input)
        message = messages.fields_message(scene.fields, cloud, world_from_input)
        self.node.publish(self.node.keys.fields, message)
        set_time(self.node.recording, messages.seconds(cloud.timestamp))
        # the cloud itself is the assembler's to log: an entity comes from one process only
        log_fields(self.node.recording, scene.fields)
        levelling = "" if levelled else f"; {scene.alignment.describe()}"
        self.node.publish_status(
            messages.Status.READY,
            f"published fields {scene.fields.lattice.shape} of a {cloud.frames}-frame map{levelling}; "
            f"normals estimated at {normals.estimated:,} of {len(normals.points):,} thinned points",
        )

    def _superseded(self) -> bool:
        """A newer map came while these fields were computed: inference would map them only to map the newer
        ones after, each on the cores the other needs, so they are not published. Never twice in a row: at
        least every other map's fields go out, however fast maps come."""
        return (
            self.node.settings.service.hold_back_superseded
            and not self.held_back_last
            and self.inbox.supersedes(self.node.keys.cloud)
        )
