"""Operator tools over Zenoh: ``roger list``, ``status``, ``echo``, ``hz``, ``control``.

Each is a ``roger`` subcommand (module with ``configure``/``run``) that opens one Zenoh session
the way the daemon does (:mod:`roger_daemon.tools.common`), does its job within a deadline, and
exits 0 on success, 1 when the system did not answer, 2 for a bad command line.
"""
