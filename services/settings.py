"""The services' settings: the library's (affordcore.settings) and the processes' own, from the same
AFFORD_* environment variables."""

from __future__ import annotations

from pydantic import BaseModel, Field

from affordcore.settings import Settings


class NodeSettings(BaseModel):
    """What every service process shares (AFFORD_SERVICE__*)."""

    mode: str = Field(
        "peer",
        pattern="^(peer|client)$",
        description="zenoh mode of the services and clients: peer or client (--connect names the router)",
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
        description="scans waiting beyond this are refused on the assembler's error key, not dropped "
        "silently",
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
