"""Allow ``python -m roger_daemon`` as an alias of the ``roger`` command."""

from __future__ import annotations

from roger_daemon.cli import main

raise SystemExit(main())
