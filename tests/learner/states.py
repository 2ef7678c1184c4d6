"""State dicts of older schemas, for the migration tests: a current state rewritten."""

from __future__ import annotations

import json
from collections.abc import Iterable

import numpy as np


def with_schema(state: dict[str, np.ndarray], schema: int, *, drop: Iterable[str] = (),
                drop_params: Iterable[str] = ()) -> dict[str, np.ndarray]:
    """A copy of ``state`` that says it is of ``schema``, without the arrays ``drop`` and the
    parameters ``drop_params`` (what that schema did not have yet)."""
    out = dict(state)
    meta = json.loads(str(out["meta"]))
    meta["schema"] = schema
    for key in drop_params:
        del meta["params"][key]
    out["meta"] = np.array(json.dumps(meta))
    for key in drop:
        del out[key]
    return out
