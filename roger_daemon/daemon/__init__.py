"""The learner daemon (``roger daemon``): one process serving the robots of its config.

:mod:`.main` (start-up, the command), :mod:`.robot` (one robot: pairing, queue, labels,
counters; its checkpointed state in :mod:`.robot_state`, the pairing rule in :mod:`.pairing`),
:mod:`.service` (the single event loop), :mod:`.resume` (models from checkpoints and the
log tail), :mod:`.checkpoint`, :mod:`.wal` and :mod:`.retention` (durability,
docs/durability.md), :mod:`.learners` and :mod:`.worker` (learner worker processes),
:mod:`.health`, :mod:`.sdnotify`, :mod:`.window` and :mod:`.memory` (status and systemd).
"""
