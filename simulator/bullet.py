"""pybullet, imported without its build banner on stderr.

pybullet's C extension prints ``pybullet build time: ...`` to file descriptor 2 when it is
imported, whatever ``--log-level`` says (issue 56). Every simulator module imports pybullet
from here: the banner is caught while the extension loads and logged at debug level instead.

    from simulator.bullet import p
"""

from __future__ import annotations

import logging
import os
import tempfile
from typing import Any

__all__ = ["p"]

log = logging.getLogger(__name__)


def _quiet_import() -> Any:
    """``import pybullet`` with fd 2 pointed at a temporary file; its text goes to the log."""
    with tempfile.TemporaryFile() as caught:
        saved = os.dup(2)
        try:
            os.dup2(caught.fileno(), 2)
            import pybullet
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        caught.seek(0)
        text = caught.read().decode("utf-8", "replace").strip()
    if text:
        log.debug("%s", text)
    return pybullet


p = _quiet_import()
