"""Model inference: fields in, affordance/<name> out, one AffordanceMap per model (the shipped models unless
others are configured). Scoring and maps are affordcore.mapping.pipeline's `map_affordances`.

One robot (`afford serve inference --robot R`): every fields message of R is mapped. A sharded worker (`afford
serve inference --robots '*'`, a node with `WorkerKeys`) maps only its share of the fields of every robot it
selects, and picks up the share of a worker that leaves (services/shard.py, docs/deploy.md)."""

from __future__ import annotations

import threading
import time

from affordcore.geometry.features import FeatureLayout
from affordcore.mapping.next_views import suggest_views
from affordcore.mapping.pipeline import RoomMapper, Superseded, preload
from affordcore.mapping.recording import log_map, log_views, set_time
from affordcore.mapping.recording import preload as preload_recording
from affordwire import messages

from .node import Inbound, Node, unused_path
from .shard import KeyedInbox, LatestOutputs, Membership, WorkerKeys, owner
from .transport import Keys, encoding_of, robot_of, schema_of


def ros_output(node: Node, models, robot: str | None = None):
    """The maps' ROS 2 topics when AFFORD_ROS__MAPS asks for them (docs/ros.md), else None."""
    if not node.settings.ros.maps:
        return None
    from .ros_maps import RosMapOutput

    return RosMapOutput(node, [model.affordance for model in models], robot)


class InferenceService:
    def __new__(cls, node: Node):
        if isinstance(node.keys, WorkerKeys):  # one class in the registry; a sharded node gets the worker
            return super().__new__(ShardedInference)
        return super().__new__(cls)

    def __init__(self, node: Node):
        self._take_models(node)
        # the robot's room, updated; scored in worker processes when the registry forked them
        self.mapper = getattr(node, "mapper", None) or RoomMapper(self.models, self.layout, node.settings)
        self.inbox = node.inbox(latest_only=True)
        self.inbox.check = self._check  # fields are found sound before they supersede any
        # a newer map reaching the features service, or newer fields arriving, while maps are made supersede
        # them: the maps in hand are given up, except right after a call given up, so that at least every
        # other fields message gets its maps
        self.mapping = self.gave_up_last = False
        self.mapping_cloud = 0  # nanoseconds: the time of the map whose fields are being mapped
        self.features_newest = 0  # nanoseconds: the newest map the features service said it received
        self.given_up = 0
        # the input last given up, set aside: mapped after all if the newer map it yielded to is refused
        self.given_up_last_item: Inbound | None = None
        self.inbox.on_queued = self._give_up
        node.hold(node.session.declare_subscriber(node.keys.status("features"), self._features_status))
        node.subscribe(node.keys.fields, self.inbox)
        for model in self.models:
            node.answer_latest(node.keys.affordance(model.affordance))
        if node.settings.next_views.count:
            node.answer_latest(node.keys.next_views)
        self.ros = ros_output(node, self.models, node.keys.robot)
        node.fetch_latest(node.keys.fields, self.inbox)  # fields published before this service (re)started
        node.on_reset = self.forget

    def forget(self) -> None:
        """At an operator's reset: the old room's scores are not kept to update from."""
        self.mapper.forget()
        self.given_up_last_item, self.gave_up_last = None, False

    def _take_models(self, node: Node) -> None:
        """What every inference service holds of its models, and loads before the first fields arrive."""
        self.node, self.models = node, node.models
        self.ids = {model.affordance: model.id for model in self.models}  # once: an id serialises the trees
        self.layout = FeatureLayout.from_settings(node.settings)
        preload()  # the scoring modules and the second stage's kernels, now
        preload_recording()  # the first map's logging imports matplotlib's colours

    def run(self) -> None:
        self.node.run(self.inbox, self.handle, on_stop=self._ros_summary)

    def _ros_summary(self) -> str:
        return self.ros.summary() if self.ros is not None else "no ROS 2 output (AFFORD_ROS__MAPS)"

    def _fields(self, message: messages.SceneFieldsMessage):
        """The fields of a message, at the resolution the models need (or refused)."""
        settings = self.node.settings
        fields = messages.scene_fields(message, settings.limits, settings.voxel.max_voxels)
        if abs(fields.lattice.resolution - self.node.settings.voxel.resolution) > 1e-9:
            raise messages.MessageError(
                f"fields at {fields.lattice.resolution} m voxels; the models here need "
                f"{self.node.settings.voxel.resolution} m (AFFORD_VOXEL__RESOLUTION of the features service)"
            )
        if (fields.soft_occupancy is not None) != self.layout.soft_fields:
            kinds = ("binary", "soft") if self.layout.soft_fields else ("soft", "binary")
            raise messages.MessageError(
                f"{kinds[0]} fields; the models here were trained on {kinds[1]} ones "
                "(AFFORD_VOXEL__FIELDS of the features service)"
            )
        if fields.normal_estimator != self.layout.normal_estimator:
            raise messages.MessageError(
                f"fields with normals by '{fields.normal_estimator}'; the models here were trained with "
                f"'{self.layout.normal_estimator}' (AFFORD_NORMALS__ESTIMATOR of the features service)"
            )
        if fields.steep_facing != self.layout.steep_facing:
            raise messages.MessageError(
                f"fields with steep normals facing '{fields.steep_facing}'; the models here were trained "
                f"with '{self.layout.steep_facing}' (AFFORD_NORMALS__STEEP_FACING of the features service)"
            )
        return fields

    def _check(self, item: Inbound, parsed) -> tuple:
        """On arrival: the fields message and its fields, checked against the limits and the models."""
        message = self.node.decode(item, messages.SceneFieldsMessage, parsed=parsed)
        return message, self._fields(message)

    def handle(self, item: Inbound) -> None:
        message, fields = item.checked
        self.given_up_last_item = None
        self.node.publish_status(messages.Status.BUSY, f"mapping {len(self.models)} affordances")
        set_time(self.node.recording, messages.seconds(message.cloud_timestamp))

        def publish(affordance: str, amap) -> None:
            out = messages.map_message(amap, self.ids[affordance], message)
            self.node.publish(self.node.keys.affordance(affordance), out)
            if self.ros is not None:
                self.ros.publish(self.node.keys.robot, out)
            log_map(self.node.recording, amap)

        self.mapping_cloud, self.mapping = messages.nanoseconds(message.cloud_timestamp), True
        try:
            if self.features_newest > self.mapping_cloud and self._may_give_up():
                raise Superseded("a newer map reached the features service before these maps began")
            maps = self.mapper.maps(fields, on_map=publish)
        except Superseded:
            self.gave_up_last, self.given_up = True, self.given_up + 1
            self.inbox.set_aside(item)  # the newer map may yet be refused
            self.given_up_last_item = item
            self.node.publish_status(
                messages.Status.READY,
                f"gave up the maps of a {message.frames}-frame map for a newer map ({self.given_up} in all)",
            )
            return
        finally:
            self.mapping = False
        self.gave_up_last = False
        views = self._suggest_views(maps, fields, message)
        self.node.publish_status(
            messages.Status.READY,
            f"published {len(self.models)} maps{views} of a {message.frames}-frame map; "
            + self.mapper.describe(self.ids),
        )

    def _suggest_views(self, maps: dict, fields, message: messages.SceneFieldsMessage) -> str:
        """Where to look next to settle this robot's maps, over every affordance (AFFORD_NEXT_VIEWS__COUNT),
        published on next-views (and to ROS 2 and the recording); what the status says of them."""
        settings = self.node.settings
        if not settings.next_views.count:
            return ""
        if fields.visibility is None:
            return " (no next views: the fields carry no sensor positions)"
        views = suggest_views(fields, maps.values(), settings)
        out = messages.next_views_message(views, settings.next_views, message)
        self.node.publish(self.node.keys.next_views, out)
        if self.ros is not None:
            self.ros.publish_views(self.node.keys.robot, out)
        log_views(self.node.recording, views, settings.next_views)
        return f" and {len(views)} next views"

    def _may_give_up(self) -> bool:
        return not self.gave_up_last and self.node.settings.service.give_up_stale_maps

    def _give_up(self) -> None:
        """A newer map is on its way (on zenoh's thread): give up the maps in hand, unless the last maps were
        given up."""
        if self.mapping and self._may_give_up():
            self.mapper.cancel()

    def _features_status(self, sample) -> None:
        """The features service's status: a map newer than the one being mapped has reached it (its newest
        input), so these maps will be stale before they are done. A status that does not parse, or whose time
        is out of bounds (as `Node` checks every input's), is ignored."""
        try:
            status = messages.parse(messages.Status, sample.payload.to_bytes())
            messages.checked_seconds(status.newest_input, self.node.settings.limits, "newest_input")
        except messages.MessageError:
            return
        # not the largest ever seen: a map the features service refuses is no longer its newest
        self.features_newest = messages.nanoseconds(status.newest_input)
        if self.mapping and self.features_newest > self.mapping_cloud:
            self._give_up()
        given_up = self.given_up_last_item
        if not self.mapping and given_up is not None:
            cloud = messages.nanoseconds(given_up.checked[0].cloud_timestamp)
            if self.features_newest <= cloud and self.inbox.recall(given_up):
                self.given_up_last_item = None  # the map it was given up for was refused: mapped after all


class ShardedInference(InferenceService):
    """One worker of a group sharing the fields of many robots: it takes a unit (a robot's affordance, or a
    robot) only when it owns it among the live workers (services/shard.py), and maps an input only when no
    map of that cloud (or a newer one) has gone out. When a worker leaves, each survivor fetches the latest
    fields of every robot one of whose units it now owns; the same rule maps exactly what is missing.

    Every worker keeps the newest map of every unit seen on the wire (its own and the others'), so that the
    owner answers a late `get` (afford watch) even for maps a worker now gone published."""

    def __init__(self, node: Node):
        self._take_models(node)
        self.keys = node.keys
        service = node.settings.service
        self.inbox = KeyedInbox(service.max_queue, service.max_queue_bytes)
        self.maps = LatestOutputs()
        self.ros = ros_output(node, self.models)
        self.robots: set[str] = set()  # every robot whose fields or maps this worker has seen
        self.recordings: dict[str, object] = {}
        self.mappers: dict[str, RoomMapper] = {}  # each robot's room, updated as its fields come
        self.recovered = 0  # inputs fetched again because a worker left
        self._lock = threading.Lock()
        self.members = Membership(self.keys.worker, self._on_members)
        session = node.session
        for key in self.keys.selection.keys("affordance", "*"):  # the maps on the wire, whoever published
            node.hold(session.declare_subscriber(key, self._take_map))
        node.hold(
            session.liveliness().declare_subscriber(self.keys.members, self.members.on_sample, history=True)
        )
        for key in self.keys.selection.keys("affordance", "*"):  # before our token: the owners still answer
            for reply in session.get(key, timeout=5.0):
                if reply.ok is not None:
                    self._take_map(reply.ok)
        node.hold(session.liveliness().declare_token(self.keys.member))
        self._reconcile()
        for key in self.keys.selection.keys("fields"):
            node.subscribe(key, self.inbox, accept=self._wanted)
        for key in self.keys.selection.keys("affordance", "*"):
            node.hold(session.declare_queryable(key, self._answer))
        for key in self.keys.selection.keys("fields"):  # fields published before this worker (re)started
            node.fetch_latest(key, self.inbox, accept=self._wanted)
        print(
            f"[{node.service}] worker {self.keys.worker} of group {self.keys.group} ({self.keys.member}): "
            f"robots {self.keys.selection}, one owner per {self.keys.unit}; live workers "
            f"{sorted(self.members.view())}",
            flush=True,
        )
        if node.settings.next_views.count:  # one robot's maps may be made by several workers
            print(
                f"[{node.service}] no next views from a sharded worker (AFFORD_NEXT_VIEWS__COUNT): a robot "
                "that wants them gets its own inference service (afford serve inference --robot R)",
                flush=True,
            )

    # -- ownership -----------------------------------------------------------------------------------------

    def owned(self, robot: str) -> list:
        """The models whose unit of `robot` this worker owns among the live workers now."""
        view = self.members.view()
        me = self.keys.worker
        return [m for m in self.models if owner(view, self.keys.unit_of(robot, m.affordance)) == me]

    def _wanted(self, key: str) -> bool:
        """A fields sample is read only when this worker owns one of its robot's units (others pass it)."""
        robot = robot_of(key)
        if robot is None:
            return False
        with self._lock:
            self.robots.add(robot)
        return bool(self.owned(robot))

    def _on_members(self, before: frozenset, after: frozenset) -> None:
        """A worker joined or left: for every robot one of whose units is newly ours, fetch its latest fields
        (on a thread of its own: never a get inside a zenoh callback)."""
        me = self.keys.worker
        with self._lock:
            robots = sorted(self.robots)
        gained = [
            robot
            for robot in robots
            if any(
                owner(after, unit) == me and owner(before, unit) != me
                for unit in (self.keys.unit_of(robot, m.affordance) for m in self.models)
            )
        ]
        left, joined = sorted(before - after), sorted(after - before)
        print(
            f"[{self.node.service}] workers now {sorted(after)} (left: {left or '-'}, joined: "
            f"{joined or '-'}); taking over units of {gained or 'no robot'}",
            flush=True,
        )
        if gained:
            threading.Thread(target=self._recover, args=(gained,), daemon=True).start()

    def _recover(self, robots: list[str]) -> None:
        for robot in robots:
            if self.node.stop_event.is_set():
                return
            try:
                taken = self.node.fetch_latest(Keys(robot).fields, self.inbox, accept=self._wanted)
            except Exception as error:  # noqa: BLE001 - the session closing under us at the stop
                print(f"[{self.node.service}] could not fetch the fields of {robot}: {error}", flush=True)
                continue
            with self._lock:
                self.recovered += taken

    def _reconcile(self) -> None:
        """The view from a liveliness get: what the tokens say now."""
        workers = [
            str(reply.ok.key_expr).rsplit("/", 1)[-1]
            for reply in self.node.session.liveliness().get(self.keys.members, timeout=2.0)
            if reply.ok is not None
        ]
        self.members.reconcile(workers)

    # -- the maps on the wire ------------------------------------------------------------------------------

    def _take_map(self, sample) -> None:
        key = str(sample.key_expr)
        robot = robot_of(key)
        if robot is None or schema_of(sample) != messages.schema_name(messages.AffordanceMapMessage):
            return
        payload = sample.payload.to_bytes()
        try:
            stamp = messages.nanoseconds(
                messages.parse(messages.AffordanceMapMessage, payload).cloud_timestamp
            )
        except messages.MessageError:
            return  # not ours to answer for (the router's access control decides who may write maps)
        with self._lock:
            self.robots.add(robot)
        self.maps.take(key, stamp, payload, sample.encoding)

    def _answer(self, query) -> None:
        """A get on maps: the owner of each unit answers with the newest map of it seen on the wire."""
        import zenoh

        asked = zenoh.KeyExpr(str(query.key_expr))
        for key, (_, payload, encoding) in self.maps.items():
            robot, affordance = key.split("/")[2], key.rsplit("/", 1)[-1]
            if not asked.intersects(zenoh.KeyExpr(key)):
                continue
            if self.members.owns(self.keys.unit_of(robot, affordance)):
                query.reply(key, payload, encoding=encoding)

    # -- the work ------------------------------------------------------------------------------------------

    def run(self) -> None:
        last = [time.monotonic()]

        def idle() -> None:  # now and then, the view from the tokens themselves
            if time.monotonic() - last[0] > self.node.settings.service.status_period:
                last[0] = time.monotonic()
                self._reconcile()

        self.node.run(self.inbox, self.handle, idle, on_stop=self._close_recordings)

    def handle(self, item: Inbound) -> None:
        robot = robot_of(item.key)
        if robot is None:
            raise messages.MessageError(f"{item.key} is not a robot's fields key")
        keys = Keys(robot)
        message = self.node.decode(item, messages.SceneFieldsMessage)
        stamp = messages.nanoseconds(message.cloud_timestamp)
        todo = [
            model
            for model in self.owned(robot)
            if self.maps.stamp(keys.affordance(model.affordance)) < stamp  # no map of it (or newer) out
        ]
        if not todo:
            self.node.publish_status(
                messages.Status.READY, f"nothing of {robot}'s fields to map here (another's, or mapped)"
            )
            return
        fields = self._fields(message)
        affordances = [model.affordance for model in todo]
        names = ", ".join(affordances)
        self.node.publish_status(messages.Status.BUSY, f"mapping {names} of {robot}")
        recording = self._recording(robot)
        set_time(recording, messages.seconds(message.cloud_timestamp))

        def publish(affordance: str, amap) -> None:
            out = messages.map_message(amap, self.ids[affordance], message)
            key = keys.affordance(affordance)
            encoding = encoding_of(messages.AffordanceMapMessage)
            self.maps.take(key, stamp, out.SerializeToString(), encoding)  # answered from here on
            self.node.publish(key, out, keep=False)
            if self.ros is not None:
                self.ros.publish(robot, out)
            log_map(recording, amap)

        if robot not in self.mappers:
            self.mappers[robot] = RoomMapper(self.models, self.layout, self.node.settings)
        self.mappers[robot].maps(fields, on_map=publish, models=todo)
        self.node.publish_status(
            messages.Status.READY,
            f"published {names} of {robot} ({message.frames}-frame map; "
            f"{self.mappers[robot].describe(affordances)})",
        )

    def _recording(self, robot: str):
        """The worker's recording of one robot, `<rrd>-<robot>.rrd`, with that robot's recording id (it opens
        with the robot's other recordings as one)."""
        from affordcore.mapping.recording import open_recording, recording_name

        if robot not in self.recordings:
            rrd = self.node.rrd
            path = unused_path(rrd.with_name(f"{rrd.stem}-{robot}{rrd.suffix}"))
            recording_id = self.node.settings.service.recording_id or f"afford-{robot}"
            affordances = [model.affordance for model in self.models]
            self.recordings[robot] = open_recording(
                path, affordances, recording_id, name=recording_name(robot)
            )
        return self.recordings[robot]

    def _close_recordings(self) -> str:
        from affordcore.mapping.recording import close_recording

        for recording in self.recordings.values():
            close_recording(recording)
        return (
            (f"{self.ros.summary()}; " if self.ros is not None else "")
            + f"worker {self.keys.worker}: recordings of {len(self.recordings)} robots closed; "
            f"{self.recovered} inputs fetched again after a worker left; "
            f"{len(self.maps.items())} maps held ({self.maps.nbytes() / 2**20:.1f} MB)"
        )
