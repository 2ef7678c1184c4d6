"""The AIBO soccer simulator (pybullet), the hand-coded FSM, and the experiment orchestrator.

* ``config``: every simulator parameter (frozen dataclasses, TOML overrides);
* ``field``: building the scene (field, goals, beacons, ball, ERS-7-like robot);
* ``world``: the pybullet world: state, walk engine, trap and kick;
* ``vision``: rendered (TinyRenderer segmentation) and fast (analytic + ray casts) blob vision;
* ``episodes``: the 13 start locations, seeding, termination, :class:`SoccerSim`, ``run_episode``;
* ``hcc``: the seek/trap/aim/kick FSM; ``aliasing``: the perceptual-aliasing measure;
* ``sim_node`` (``sim_args``) / ``hcc_node``: ``roger sim`` / ``roger hcc``; ``transport``:
  Zenoh plumbing of the nodes;
* ``launch`` / ``supervise``: ``roger up`` (daemon, simulator and controller from one file);
* ``commands``: the ``roger`` subcommands of this package (the ``roger.commands`` entry point);
* ``bench``: ``roger bench sim``; ``plot``: top-down episode plots;
* ``experiment``: the goal-scoring experiment (separate owner).
"""

from __future__ import annotations

__all__: list[str] = []
