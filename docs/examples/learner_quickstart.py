"""ROGER's learner on made-up data, with the recommended settings (runs as pasted).

One input x in [0, 1], one output y, demonstrated by two "subtasks" taking turns: y = +sqrt(x)
and y = -sqrt(x). Plain regression averages them to 0 everywhere; ROGER learns both branches
(a multimap) and which points belong to which.

The recommended settings are the "default" preset with the ranges of your data declared, so
the learner sees them scaled to [-1, 1] (predictions come back in your units). Run it:

    python docs/examples/learner_quickstart.py
"""

import numpy as np

from roger_daemon.learner import Roger, RogerParams

rng = np.random.default_rng(0)
n = 400
x = rng.uniform(0.0, 1.0, size=(n, 1))                      # perception: (n, d_x)
subtask = np.arange(n) % 2                                   # who demonstrated (not learned)
y = np.where(subtask[:, None] == 0, 1.0, -1.0) * np.sqrt(x)  # action: (n, d_y)
y += rng.normal(0.0, 0.02, size=y.shape)

params = RogerParams.preset("default", x_ranges=[(0.0, 1.0)], y_ranges=[(-1.0, 1.0)])
model = Roger(d_x=1, d_y=1, params=params, seed=0)
for xi, yi in zip(x, y, strict=True):
    model.learn_one(xi, yi)                                  # online, one pair at a time

query = np.array([0.5])
pred = model.predict_one(query)                              # the most probable expert
print(f"learned {model.n_learned} pairs into {model.n_experts} experts")
print(f"prediction at x=0.5: mean {pred.mean[0]:+.3f}, variance {pred.var[0]:.2g}, "
      f"expert {pred.expert_id}")
branches = sorted(model.predict_multimap(query), key=lambda b: -b.gate_prob)
for b in branches[:3]:                                       # every expert, by gate probability
    print(f"  expert {b.expert_id:3d}: mean {b.mean[0]:+.3f} (p = {b.gate_prob:.2f})")

# how well the segmentation matches the subtasks (purity: 1.0 = every expert holds one)
assigned = np.asarray(model.assignments())
purity = sum(np.bincount(subtask[assigned == e]).max() for e in set(assigned)) / n
print(f"purity of the experts against the subtasks: {purity:.2f}")

both = {round(float(np.sign(b.mean[0]))) for b in branches[:2]}
assert both == {-1, 1}, "the two most probable experts are the two branches"
