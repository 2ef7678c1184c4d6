"""What the wire says about one message field beyond its Python type.

Every field of the message dataclasses (:mod:`protocols.message_types`) carries a
:class:`FieldSpec` in its ``dataclasses.field(metadata=...)``: its description and its
constraints. The JSON Schemas of the MCAP files (``roger_daemon.recording.schemas``) are
generated from these and the field types, so the field lists are written once.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["FieldSpec", "field_spec", "spec"]

_KEY = "roger"


@dataclass(frozen=True)
class FieldSpec:
    """Description and constraints of one wire field.

    ``minimum``: the least value of an integer (``None``: unbounded); ``positive``: every entry
    of a vector is > 0; ``choices``: the values a string may take (empty: any string of at most
    ``MAX_STR`` bytes); ``pattern``: a regular expression the string matches instead (no length
    limit beyond the pattern's).
    """

    description: str
    minimum: int | None = 0
    positive: bool = False
    choices: tuple[str, ...] = ()
    pattern: str = ""


def spec(
    description: str,
    *,
    minimum: int | None = 0,
    positive: bool = False,
    choices: tuple[str, ...] = (),
    pattern: str = "",
) -> Mapping[str, FieldSpec]:
    """The ``metadata`` of a message field: ``field(metadata=spec("...", positive=True))``."""
    return {_KEY: FieldSpec(description, minimum, positive, choices, pattern)}


def field_spec(f: dataclasses.Field[Any]) -> FieldSpec:
    """The :class:`FieldSpec` of a dataclass field; ``KeyError`` if it has none."""
    try:
        out: FieldSpec = f.metadata[_KEY]
    except KeyError:
        raise KeyError(f"field {f.name!r} has no FieldSpec in its metadata") from None
    return out
