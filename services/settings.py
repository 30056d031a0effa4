"""The services' settings: the library's (affordcore.settings) and the processes' own, from the same
AFFORD_* environment variables."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, Field

from affordcore.settings import Settings


class NodeSettings(BaseModel):
    """What every service process shares (AFFORD_SERVICE__*)."""

    mode: str = Field(
        "client",
        pattern="^(peer|client)$",
        description="zenoh mode of the services and clients: client talks only through the router named by "
        "--connect, so its access control cannot be bypassed; peer also links processes directly",
    )
    zenoh_config: Path | None = Field(
        None,
        description="a zenoh JSON5 config file (TLS certificates, access control, ...) the session starts "
        "from; --connect, --listen and the mode are set on top of it (docs/security.md)",
    )
    recording_id: str = Field(
        "",
        description="Rerun recording id every service shares, so their .rrd files open as one recording; "
        "empty: afford-<robot>",
    )
    status_period: float = Field(5.0, gt=0, description="each service republishes its status this often (s)")
    max_queue: int = Field(
        1000,
        ge=1,
        description="inputs waiting beyond this are refused on the service's error key, not dropped silently",
    )
    max_queue_bytes: int = Field(
        512 * 2**20,
        ge=2**20,
        description="... or beyond this many bytes waiting (one payload larger than this is refused)",
    )
    max_lag: float = Field(
        0.5,
        gt=0,
        description="the assembler passes over a scan that waited longer than this (s) when a newer one "
        "waits, and says so on its status key: it follows the sensor instead of falling behind",
    )
    max_gap: float = Field(
        0.5,
        gt=0,
        description="... as long as the next one waiting arrived within this many seconds of the last scan "
        "taken: the frames registered are never further apart (registration bridges a short gap, its "
        "motion guess spanning the gap's time, not a long one)",
    )
    state: Path | None = Field(
        None,
        description="assembler: folder of its checkpoint (map, trajectory, and a journal of every frame "
        "since), reloaded on start; none: the map lives in memory only",
    )
    downstream_nice: int = Field(
        10,
        ge=0,
        le=19,
        description="features and inference run this much nicer than the assembler, "
        "so scan assembly keeps up with the sensor on a shared CPU",
    )


class ServiceSettings(Settings):
    """Everything a service process reads: the library's settings and `service` (AFFORD_SERVICE__*)."""

    service: NodeSettings = NodeSettings()
