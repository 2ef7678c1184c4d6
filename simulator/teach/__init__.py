"""``roger teach``: a person demonstrates, watches and corrects the robot from a web page.

The simulator's loop (:mod:`.loop`), the robot's own controller (:mod:`.autonomy`), the
page's input channel (:mod:`.channel`), its server (:mod:`.server`), the session's parts
(:mod:`.session`) and the command (:mod:`.cli`); the scripted teacher (:mod:`.scripted`) and
``roger experiment teach`` / ``roger bench teach`` drive the page's own channel. docs/teach.md.
"""

from __future__ import annotations

__all__: list[str] = []
