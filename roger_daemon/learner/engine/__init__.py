"""The learner's engine: compiled kernels, buffers and packed storage, and the store of
experts in slots, under the paper's classes (docs/learner-api.md, *The engine*).

Everything here takes arrays, slot indices and expert slabs (:mod:`.jit_slab`) and imports
none of the paper's classes (``Roger``, ``SparseOnlineGP``, ``NIWGate``, ``RogerParams``):
the paper's modules above call it, never the other way round (tests/test_import_graph.py).

* the compiled kernels, ``jit_*.py`` (numba), reached through :mod:`.jit`, which loads them
  on first use; numba's on-disk cache is tied to their sources (:mod:`.jit_compile`), and
  ``roger compile`` fills it (:mod:`.jit_warm`);
* :mod:`.packed`: the packed symmetric storage of an expert's ``C`` and ``Q``;
* :mod:`.buffers`: the dropped experts' slabs, reused by copy-on-write copies;
* :mod:`.gates`: every expert's NIW gate, stacked by slot, evaluated in one call.

Each compiled kernel is a drop-in for plain numpy or Python code, tested against it
(tests/learner/test_jit*.py, test_gate.py, test_resampling.py).
"""
