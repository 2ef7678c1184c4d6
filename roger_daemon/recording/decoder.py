"""Decoding ROGER's MCAP logs with the ``mcap`` library itself: a msgpack ``DecoderFactory``.

The session logs carry msgpack payloads (message encoding ``msgpack``) described by JSON
Schemas (``roger.<kind>``, :mod:`roger_daemon.recording.schemas`). ``mcap`` ships decoders for
ROS, protobuf and JSON only, so without this factory its ``iter_decoded_messages`` stops with
``DecoderNotFoundError``. With it, every message of a recording decodes to the same plain map
(string keys, lists of floats, nested maps) that the schema describes and that ``roger log
export --format json`` writes::

    from mcap.reader import make_reader
    from roger_daemon.recording.decoder import DecoderFactory

    with open("roger-aibo-20261123T070929Z.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, value in reader.iter_decoded_messages():
            print(channel.topic, value["tick"])

The raw bytes stay in the file (``message.data``): replay reads those, never a re-encoding.
Extension types, which the protocol never uses, are refused (``ValueError``), as by the
daemon's own decoder.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import msgpack
from mcap.decoder import DecoderFactory as _McapDecoderFactory
from mcap.records import Schema

__all__ = ["MESSAGE_ENCODING", "DecoderFactory", "decode_msgpack"]

#: the message encoding of every channel ROGER records
MESSAGE_ENCODING = "msgpack"


class _ExtensionType(ValueError):
    """An extension type in a payload (not part of the protocol)."""


def _no_ext(code: int, data: bytes) -> Any:
    raise _ExtensionType(f"msgpack extension type {code} ({len(data)} bytes) is not allowed")


def decode_msgpack(data: bytes) -> Any:
    """One msgpack payload as plain Python values (``ValueError`` if it is not msgpack)."""
    try:
        return msgpack.unpackb(data, raw=False, strict_map_key=False, ext_hook=_no_ext)
    except _ExtensionType:
        raise
    except Exception as exc:  # msgpack's own errors (ExtraData, FormatError, StackError)
        raise ValueError(f"not a msgpack payload: {exc}") from None


class DecoderFactory(_McapDecoderFactory):
    """``mcap``'s decoder factory for ``msgpack`` channels (with or without a schema)."""

    def decoder_for(self, message_encoding: str, schema: Schema | None
                    ) -> Callable[[bytes], Any] | None:
        """:func:`decode_msgpack` for msgpack channels, ``None`` for any other encoding."""
        return decode_msgpack if message_encoding == MESSAGE_ENCODING else None
