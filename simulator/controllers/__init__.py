"""The controllers that drive the simulated AIBO: the hand-coded FSM (:mod:`.hcc`), its Zenoh
node as demonstrator or transitioner (:mod:`.hcc_node`), and the transitioner's choice among
ROGER's experts (:mod:`.transitioner`); and :mod:`.play_node`, ``roger play``: ROGER's experts
chosen by their learned transitions, with none of the hand-coded controller (docs/autonomy.md)."""
