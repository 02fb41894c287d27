"""rmw_zenoh's bytes outside the payload: data keys, the attachment, liveliness tokens and their QoS string.

Follows ros2/rmw_zenoh docs/design.md and liveliness_utils.cpp (Jazzy, 0.2.x). Where they leave a choice:
node id 0 and entity ids counting from 1 within the session, the GID is XXH3-128 of the entity's token key (as
rmw_zenoh computes it, low 64 bits first), the enclave is empty (``%``).
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass

import xxhash

from hild.api.ros2.types import dds_name, type_hash

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION, SERVICE = "NN", "MP", "MS", "SS"
GID_SIZE = 16
_ATTACHMENT = struct.Struct("<qqB16s")  # sequence number, source timestamp (ns), GID length, GID
ATTACHMENT_SIZE = _ATTACHMENT.size  # 33


def mangle(name: str) -> str:
    """``/`` → ``%``; an empty name is ``%`` (a Zenoh key chunk cannot be empty)."""
    return name.replace("/", "%") or "%"


def qualify(namespace: str, name: str) -> str:
    """A relative name in ``namespace``: ``/`` + ``joint_states`` → ``/joint_states``."""
    return f"{namespace.rstrip('/')}/{name.strip('/')}"


@dataclass(frozen=True)
class Qos:
    """The QoS an entity advertises; rmw_zenoh writes only what differs from its default profile
    (reliable, volatile, keep-last; deadline, lifespan and liveliness left at default)."""

    depth: int = 10
    best_effort: bool = False
    transient_local: bool = False

    def keyexpr(self) -> str:
        reliability = "2" if self.best_effort else ""
        durability = "1" if self.transient_local else ""
        return f"{reliability}:{durability}:,{self.depth}:,:,:,,"


DEFAULT_QOS = Qos()
LATCHED_QOS = Qos(depth=1, transient_local=True)


def data_key(domain_id: int, name: str, type_name: str, distro: str = "jazzy") -> str:
    """``<domain>/<name without outer slashes>/<dds type>/<RIHS01 hash>``: topics and services alike."""
    return f"{domain_id}/{name.strip('/')}/{dds_name(type_name)}/{type_hash(type_name, distro)}"


@dataclass(frozen=True)
class NodeInfo:
    domain_id: int
    zid: str
    namespace: str
    name: str
    node_id: int = 0

    def prefix(self, entity_id: int, kind: str) -> str:
        ns = mangle(self.namespace if self.namespace != "/" else "")
        return f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{entity_id}/{kind}/%/{ns}/{self.name}"

    def node_token(self) -> str:
        return self.prefix(self.node_id, NODE)

    def entity_token(
        self, entity_id: int, kind: str, name: str, type_name: str, qos: Qos = DEFAULT_QOS, distro: str = "jazzy"
    ) -> str:
        """A publisher's, subscription's or service server's token; ``name`` fully qualified."""
        parts = (mangle(name), dds_name(type_name), type_hash(type_name, distro), qos.keyexpr())
        return "/".join((self.prefix(entity_id, kind), *parts))


def gid_of(token: str) -> bytes:
    """rmw_zenoh's GID of an entity: XXH3-128 of its token key, low 64 bits then high 64, little-endian."""
    digest = xxhash.xxh3_128_intdigest(token.encode())
    return struct.pack("<QQ", digest & 0xFFFFFFFFFFFFFFFF, digest >> 64)


def attachment(sequence: int, gid: bytes, stamp_ns: int | None = None) -> bytes:
    """What rmw_zenoh attaches to every put, query and reply."""
    return _ATTACHMENT.pack(sequence, time.time_ns() if stamp_ns is None else stamp_ns, GID_SIZE, gid)


@dataclass(frozen=True)
class Attachment:
    sequence: int
    stamp_ns: int
    gid: bytes


def parse_attachment(raw: bytes | None) -> Attachment:
    """A query's or sample's attachment; ValueError when it is not rmw_zenoh's 33 bytes."""
    if raw is None or len(raw) != ATTACHMENT_SIZE:
        raise ValueError(f"attachment of {0 if raw is None else len(raw)} bytes, expected {ATTACHMENT_SIZE}")
    sequence, stamp, size, gid = _ATTACHMENT.unpack(raw)
    if size != GID_SIZE:
        raise ValueError(f"attachment GID length {size}, expected {GID_SIZE}")
    return Attachment(sequence, stamp, gid)
