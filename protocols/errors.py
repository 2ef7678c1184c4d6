"""The one error a decoder raises."""

from __future__ import annotations

__all__ = ["REASONS", "ProtocolError"]

#: Every reason a payload can be rejected for; receivers count invalid messages by these.
REASONS = (
    "oversized",  # payload larger than the limit
    "not_msgpack",  # bytes that do not parse as msgpack
    "not_a_map",  # valid msgpack whose top level is not a map
    "bad_version",  # missing or unsupported schema version `v`
    "missing_field",  # a required field is absent
    "wrong_type",  # a field has the wrong type
    "wrong_dimension",  # a vector has the wrong length
    "not_finite",  # NaN or infinity where a finite number is required
    "bad_value",  # a value outside its allowed set or range
    "unknown_robot",  # robot id not served, or not matching the key expression
    "bad_key",  # key expression not of the form roger/<robot>/<kind>
)


class ProtocolError(ValueError):
    """A payload or key that does not follow the protocol.

    Parameters
    ----------
    reason
        One of :data:`REASONS`, for counting by kind.
    message
        What was wrong, for a human (names the field, what was expected and what came).
    """

    def __init__(self, reason: str, message: str) -> None:
        if reason not in REASONS:
            raise ValueError(f"unknown ProtocolError reason {reason!r}")
        super().__init__(f"{reason}: {message}")
        self.reason = reason
        self.detail = message
