"""Which environment seeds (initial states) each use of the kitchen resets from.

The ranges are disjoint, so no score is measured on an initial state that produced training data or that the task
ladder was tuned on:
- generated datasets (`skillret-generate`): generation seed s simulates env seeds s * 1,000,003 + i, i counting the
  episodes (and failed demo attempts) of that dataset (`collect.episode_jobs`);
- evaluating trained policies (the pipeline's `lerobot-eval` runs, the examples): EVAL_SEED0 + run seed + i;
- calibrating the task ladder (`benchmarks/kitchen_learnability.py`, the BC reference's rollouts): CALIBRATION_SEED0 + i.

Not part of the kitchen fingerprint: no generated dataset depends on these numbers.
"""

EVAL_SEED0 = 100_000
CALIBRATION_SEED0 = 200_000
