"""The attachment every publish and query carries on the Zenoh transport: the sender's id, the
message kind and the requester's timeout (fault injection and diagnostics read it; anything
else there is ignored)."""

from __future__ import annotations

from typing import Annotated

import msgspec


class Meta(msgspec.Struct, array_like=True):
    """Attachment carried by every publish and query: sender id, kind, requester timeout (s)."""

    sender: Annotated[str, msgspec.Meta(max_length=64)]  # bounded: it comes from the network
    kind: Annotated[str, msgspec.Meta(max_length=64)]
    timeout_s: float = 0.0


_meta_encoder = msgspec.msgpack.Encoder()
_meta_decoder = msgspec.msgpack.Decoder(Meta)


def encode_meta(meta: Meta) -> bytes:
    """Serialise an attachment."""
    return _meta_encoder.encode(meta)


def decode_meta(data: bytes | None) -> Meta | None:
    """Parse an attachment; None if absent or not ours."""
    if not data:
        return None
    try:
        return _meta_decoder.decode(data)
    except (msgspec.DecodeError, msgspec.ValidationError):
        return None
