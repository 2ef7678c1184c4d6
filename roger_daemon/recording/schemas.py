"""JSON Schemas (draft 2020-12) of the ROGER messages and decision records, one per kind.

These are the documentation schemas registered in every MCAP file (schema encoding
``jsonschema``, schema name ``roger.<kind>``; the daemon's decision records of
:mod:`protocols.decisions` are the kinds ``daemon.<event>``). The channels themselves carry
msgpack, which has the same data model as JSON for these messages (maps with string keys,
arrays, numbers, strings), so the same schema describes the msgpack payload and the JSON that
``roger log export`` writes.

The schemas are generated from the message dataclasses of :mod:`protocols.message_types` (and
:mod:`protocols.decisions`): each
field's type gives its JSON type, its :class:`~protocols.field_specs.FieldSpec` (the field's
metadata) its description and constraints, and the class's ``DESCRIPTION`` the kind's. Tests check
that every kind's ``properties`` are exactly the keys that ``to_map`` produces, that encoded
messages validate, and that the bytes stay those of ``tests/data/schemas.json``.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from collections.abc import Mapping
from functools import cache
from typing import Any

from protocols.decisions import DECISION_TYPES
from protocols.field_specs import field_spec
from protocols.keys import KINDS
from protocols.message_types import (
    MAX_MULTIMAP,
    MAX_STR,
    MAX_VECTOR,
    SCHEMA_VERSION,
    TYPES,
    FloatArray,
)

__all__ = ["CLASSES", "SCHEMA_ENCODING", "SCHEMA_PREFIX", "schema", "schema_bytes", "schema_name"]

SCHEMA_ENCODING = "jsonschema"
SCHEMA_PREFIX = "roger."
_DRAFT = "https://json-schema.org/draft/2020-12/schema"
_SCALARS = {int: "integer", float: "number", str: "string", bool: "boolean"}

assert set(TYPES) == set(KINDS)
#: every kind with a schema: the wire's, then the decision records (``daemon.<event>``)
CLASSES = {**TYPES, **{cls.KIND: cls for cls in DECISION_TYPES.values()}}


def _scalar(hint: Any, f: dataclasses.Field[Any]) -> dict[str, Any]:
    """An integer (with its minimum), number or string (bounded, or a pattern; enum) field."""
    sp = field_spec(f)
    out: dict[str, Any] = {"type": _SCALARS[hint], "description": sp.description}
    if hint is int and sp.minimum is not None:
        out["minimum"] = sp.minimum
    if hint is str:
        if sp.pattern:
            out["pattern"] = sp.pattern
        else:
            out["maxLength"] = MAX_STR
        if sp.choices:
            out["enum"] = list(sp.choices)
    return out


def _field(hint: Any, f: dataclasses.Field[Any]) -> dict[str, Any]:
    """The schema of one field from its type hint and :class:`FieldSpec`."""
    if hint in _SCALARS:
        return _scalar(hint, f)
    sp = field_spec(f)
    if hint == FloatArray:
        item: dict[str, Any] = {"type": "number"}
        if sp.positive:
            item["exclusiveMinimum"] = 0
        return {"type": "array", "items": item, "maxItems": MAX_VECTOR,
                "description": sp.description}
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Mapping:
        out: dict[str, Any] = {"type": "object", "description": sp.description}
        if args[1] in _SCALARS:
            out["additionalProperties"] = {"type": _SCALARS[args[1]]}
        return out
    if origin is tuple and isinstance(args[0], type) and dataclasses.is_dataclass(args[0]):
        return {"type": "array", "items": _record(args[0]), "maxItems": MAX_MULTIMAP,
                "description": sp.description}
    raise TypeError(f"no JSON Schema for field {f.name!r} of type {hint!r}")


def _properties(cls: type) -> dict[str, dict[str, Any]]:
    """The schema of every dataclass field of ``cls``, in field order."""
    hints = typing.get_type_hints(cls)
    return {f.name: _field(hints[f.name], f) for f in dataclasses.fields(cls)}


def _record(cls: type) -> dict[str, Any]:
    """A closed object schema of a nested record (an entry of ``multimap``)."""
    props = _properties(cls)
    return {
        "type": "object",
        "description": cls.DESCRIPTION,  # type: ignore[attr-defined]
        "properties": props,
        "required": list(props),
        "additionalProperties": False,
    }


@cache
def _message_properties(kind: str) -> str:
    """The header ``v`` and every field of a message kind, as JSON (parsed afresh per call)."""
    cls = CLASSES[kind]
    props = {"v": {"const": SCHEMA_VERSION, "description": cls.VERSION_DESCRIPTION},
             **_properties(cls)}
    return json.dumps(props)


def schema_name(kind: str) -> str:
    """``roger.<kind>``: the MCAP schema name of a message kind."""
    return SCHEMA_PREFIX + kind


def schema(kind: str) -> dict[str, Any]:
    """The JSON Schema of one message kind (a fresh dict)."""
    if kind not in CLASSES:
        raise KeyError(f"no schema for message kind {kind!r}; kinds are {sorted(CLASSES)}")
    cls = CLASSES[kind]
    props = json.loads(_message_properties(kind))
    return {
        "$schema": _DRAFT,
        "$id": f"urn:roger:schema:{kind}:v{SCHEMA_VERSION}",
        "title": schema_name(kind),
        "description": cls.DESCRIPTION,
        "type": "object",
        "properties": props,
        "required": list(props),
        "additionalProperties": False,
    }


def schema_bytes(kind: str) -> bytes:
    """The schema as compact, key-sorted UTF-8 JSON (what goes into the MCAP Schema record)."""
    return json.dumps(schema(kind), sort_keys=True, separators=(",", ":")).encode()
