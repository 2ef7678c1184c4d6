"""The controllers that drive the simulated AIBO: the hand-coded FSM (:mod:`.hcc`), its Zenoh
node as demonstrator or transitioner (:mod:`.hcc_node`), and the transitioner's choice among
ROGER's experts (:mod:`.transitioner`)."""
