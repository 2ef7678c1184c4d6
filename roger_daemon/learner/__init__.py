"""The ROGER learner: sparse online GP experts, NIW gates, CRP particle filter.

The paper's classes on top of an engine of compiled kernels (:mod:`.engine`: numba, with
numpy and scipy); it reads and writes no file of its own, but numba keeps the compiled kernels
in its on-disk cache (:mod:`.engine.jit_compile`).  It imports nothing else of
``roger_daemon``.  The public API (``docs/learner-api.md``)::

    from roger_daemon.learner import RogerParams, Roger, UnimapGP, Prediction, ExpertPrediction
    from roger_daemon.learner import ParameterError, load_model, MODELS, PRESETS
    from roger_daemon.learner import ReferenceRoger  # Algorithms 1 and 2 in plain numpy

``Roger`` runs on compiled kernels (numba); ``ReferenceRoger`` (:mod:`.reference`) is the same
model in plain numpy and scipy, the oracle the fast one is tested against.
"""

from __future__ import annotations

from roger_daemon.learner.gate import NIWGate
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.params import PRESETS, ParameterError, RogerParams
from roger_daemon.learner.prediction import ExpertPrediction, Prediction
from roger_daemon.learner.reference import ReferenceRoger
from roger_daemon.learner.registry import MODELS, load_model
from roger_daemon.learner.resampling import fearnhead_resample
from roger_daemon.learner.roger import Roger
from roger_daemon.learner.sogp import SparseOnlineGP
from roger_daemon.learner.unimap import UnimapGP

__all__ = [
    "MODELS",
    "ExpertPrediction",
    "NIWGate",
    "PRESETS",
    "ParameterError",
    "Prediction",
    "RBFKernel",
    "ReferenceRoger",
    "Roger",
    "RogerParams",
    "SparseOnlineGP",
    "UnimapGP",
    "fearnhead_resample",
    "load_model",
]
