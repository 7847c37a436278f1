"""ROS 2's Zenoh middleware conventions (rmw_zenoh_cpp, its ``docs/design.md`` and
``liveliness_utils.cpp``), as pure functions: data key expressions, liveliness tokens, the
compact QoS string, publisher GIDs and the attachment every sample carries.

* Data key: ``<domain>/<fully qualified name without its leading />/<DDS type>/<type hash>``,
  e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...`` (:func:`data_key`). The DDS
  type of ``pkg/msg/Name`` is ``pkg::msg::dds_::Name_`` (:func:`dds_type_name`).
* Type hash: Jazzy and later put the RIHS01 hash of the type description (REP-2016) there;
  Humble writes the constant :data:`HUMBLE_TYPE_HASH`, ``TypeHashNotSupported``.
* Liveliness tokens (graph discovery, what ``ros2 topic list`` reads), with ``/`` mangled to
  ``%`` in names (:func:`mangle`):
  node ``@ros2_lv/<domain>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node name>``,
  publisher / subscription ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/MP|MS/<enclave>/
  <namespace>/<node name>/<topic>/<DDS type>/<type hash>/<qos>`` (:func:`node_token`,
  :func:`entity_token`); ``<zid>`` is the Zenoh session id as Zenoh prints it.
* QoS string ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,
  <ns>:<liveliness>,<lease s>,<ns>``, each value left empty when it is rmw_zenoh's default
  (reliable, volatile, keep last, depth 42, infinite durations, automatic liveliness), e.g.
  ``::,10:,:,:,,`` for depth 10 (:func:`qos_keyexpr`). Enum numbers are rmw's (the same as
  ``rosbags.interfaces``' Qos enums).
* GID: 16 bytes, rmw_zenoh's XXH3-128 of the entity's liveliness key expression, low 64 bits
  then high 64 bits, each little-endian (:func:`gid_of`).
* Attachment of every published sample: int64 sequence number, int64 source timestamp [ns
  since the Unix epoch], one byte GID length (16), the 16 GID bytes; all little-endian, 33
  bytes (:func:`encode_attachment`, :func:`decode_attachment`). A sample without it is
  refused by rmw_zenoh ("Unable to obtain attachment").
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from typing import Final, Literal

import xxhash
from rosbags.interfaces import QosDurability, QosHistory, QosReliability

#: The hermetic admin space of rmw_zenoh's liveliness tokens.
ADMIN_SPACE: Final = "@ros2_lv"
#: What Humble's rmw_zenoh writes in place of a type hash.
HUMBLE_TYPE_HASH: Final = "TypeHashNotSupported"
#: Entity kinds of the tokens: node, message publisher, message subscription.
NODE: Final = "NN"
PUBLISHER: Final = "MP"
SUBSCRIPTION: Final = "MS"
#: Length of a GID [bytes] and of a whole attachment [bytes].
GID_SIZE: Final = 16
ATTACHMENT_SIZE: Final = 8 + 8 + 1 + GID_SIZE

Distro = Literal["jazzy", "humble"]
#: The type-hash conventions :func:`type_hash_for` knows; the first is the default.
DISTROS: Final[tuple[Distro, ...]] = ("jazzy", "humble")

_ATTACHMENT = struct.Struct("<qqB")
_TYPE_NAME = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/msg/([A-Za-z][A-Za-z0-9_]*)$")


@dataclass(frozen=True)
class Qos:
    """The QoS a publisher offers or a subscription asks for (rmw enum values)."""

    reliability: QosReliability = QosReliability.RELIABLE
    durability: QosDurability = QosDurability.VOLATILE
    history: QosHistory = QosHistory.KEEP_LAST
    depth: int = 10


#: rmw_zenoh's defaults (``qos.cpp``): values equal to them are left out of the QoS string.
RMW_ZENOH_DEFAULT: Final = Qos(depth=42)


@dataclass(frozen=True)
class Attachment:
    """The attachment of one sample: sequence number, source time [ns since the epoch], GID."""

    sequence: int
    stamp_ns: int
    gid: bytes


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (the CDR type name of DDS and rmw_zenoh);
    ValueError for anything else."""
    m = _TYPE_NAME.fullmatch(typename)
    if m is None:
        raise ValueError(f"not a ROS 2 message type name: {typename!r}")
    return f"{m.group(1)}::msg::dds_::{m.group(2)}_"


def type_hash_for(rihs01: str, distro: Distro) -> str:
    """The type hash written in keys and tokens: the RIHS01 hash (Jazzy and later) or
    :data:`HUMBLE_TYPE_HASH` (Humble)."""
    if distro == "humble":
        return HUMBLE_TYPE_HASH
    if not rihs01.startswith("RIHS01_"):
        raise ValueError(f"not a RIHS01 hash: {rihs01!r}")
    return rihs01


def mangle(name: str) -> str:
    """A ROS name as one key chunk: every ``/`` becomes ``%`` (``/`` alone: ``%``)."""
    return name.replace("/", "%")


def data_key(domain: int, topic: str, dds_type: str, type_hash: str) -> str:
    """The key expression of a topic's samples (``topic`` fully qualified, ``/a/b``)."""
    return f"{domain}/{topic.strip('/')}/{dds_type}/{type_hash}"


def qos_keyexpr(qos: Qos) -> str:
    """The compact QoS chunk of a liveliness token (module docstring); deadline, lifespan and
    liveliness lease are always rmw_zenoh's defaults here (infinite, automatic)."""
    d = RMW_ZENOH_DEFAULT

    def differs(value: int, default: int) -> str:
        return "" if value == default else str(value)

    return ":".join([
        differs(qos.reliability.value, d.reliability.value),
        differs(qos.durability.value, d.durability.value),
        f"{differs(qos.history.value, d.history.value)},{differs(qos.depth, d.depth)}",
        ",",  # deadline s, ns: infinite
        ",",  # lifespan s, ns: infinite
        ",,",  # liveliness kind, lease s, ns: automatic, infinite
    ])


def node_token(domain: int, zid: str, node_id: int, namespace: str, node: str,
               enclave: str = "/") -> str:
    """The liveliness token of a node (``namespace`` absolute, ``/`` for none)."""
    return "/".join([ADMIN_SPACE, str(domain), zid, str(node_id), str(node_id), NODE,
                     mangle(enclave), mangle(namespace), mangle(node)])


def entity_token(domain: int, zid: str, node_id: int, entity_id: int, kind: str,
                 namespace: str, node: str, topic: str, dds_type: str, type_hash: str,
                 qos: Qos, enclave: str = "/") -> str:
    """The liveliness token of a publisher (``kind`` :data:`PUBLISHER`) or subscription
    (:data:`SUBSCRIPTION`) of node (``namespace``, ``node``) on the fully qualified
    ``topic``."""
    if kind not in (PUBLISHER, SUBSCRIPTION):
        raise ValueError(f"unknown entity kind {kind!r}")
    return "/".join([ADMIN_SPACE, str(domain), zid, str(node_id), str(entity_id), kind,
                     mangle(enclave), mangle(namespace), mangle(node), mangle(topic),
                     dds_type, type_hash, qos_keyexpr(qos)])


def gid_of(token: str) -> bytes:
    """The GID rmw_zenoh derives from an entity's liveliness token: XXH3-128 of its bytes,
    the low 64 bits then the high 64 bits, each little-endian."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


def encode_attachment(sequence: int, stamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment of one sample (module docstring)."""
    if len(gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(gid)}")
    return _ATTACHMENT.pack(sequence, stamp_ns, GID_SIZE) + gid


def decode_attachment(data: bytes | None) -> Attachment | None:
    """The attachment of a received sample, or None when it is absent or malformed."""
    if data is None or len(data) < _ATTACHMENT.size:
        return None
    sequence, stamp_ns, n = _ATTACHMENT.unpack_from(data)
    if len(data) != _ATTACHMENT.size + n:
        return None
    return Attachment(sequence, stamp_ns, bytes(data[_ATTACHMENT.size:]))
