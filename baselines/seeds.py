"""The project's seed ranges, in one place, so that training never sees an evaluation seed.

* ``[1000, 99999]`` (:data:`TRAIN_SEED_RANGE`): the Siamese tracker's training sequences
  (:mod:`baselines.lars.training.siamese`); ``train.py`` training seeds stay below
  :data:`TRAIN_EVAL_SEED_BASE` (checked in :mod:`baselines.rl.config`).
* ``10000 ...`` (:data:`DATASET_SEED_BASE`): the default seeds of expert datasets
  (:mod:`baselines.datasets`), inside :data:`TRAIN_SEED_RANGE`, clear of the Siamese
  sequences and of ``train.py``'s first seeds; a dataset that reaches
  :data:`TRAIN_EVAL_SEED_BASE` is warned about.
* ``20000 ...`` (:data:`DISTILL_SEED_BASE`): the episodes a pixel policy is distilled on
  (:mod:`baselines.rl.distill`), :data:`DISTILL_SEEDS_PER_RUN` per training seed, below
  :data:`TRAIN_EVAL_SEED_BASE`.
* ``90000 ...`` (:data:`TRAIN_EVAL_SEED_BASE`): the held-out episodes ``train.py``
  evaluates on while it trains.
* ``100000 ...`` (:data:`EVAL_SEED_BASE`): the leaderboard's frozen evaluation seeds
  (:func:`default_seeds`).

Calibration and reproduction scripts take ``--first-seed`` and document the ranges they
were run on (``docs/difficulty.md``).
"""

from __future__ import annotations

#: The leaderboard's evaluation seeds start here; training seeds stay below it.
EVAL_SEED_BASE = 100_000
#: Training-time evaluation seeds start here; training seeds stay below it, and both
#: stay below :data:`EVAL_SEED_BASE`.
TRAIN_EVAL_SEED_BASE = 90_000
#: Seeds of the Siamese tracker's training sequences (inclusive), below
#: :data:`EVAL_SEED_BASE`.
TRAIN_SEED_RANGE = (1000, 99999)
#: Expert datasets (imitation, offline RL) record from this seed by default: training
#: data, below :data:`TRAIN_EVAL_SEED_BASE` with room for 80000 episodes.
DATASET_SEED_BASE = 10_000
#: Distillation (teacher-student DAgger) episodes start here: a training seed ``s`` draws
#: from ``DISTILL_SEED_BASE + DISTILL_SEEDS_PER_RUN * s``, below :data:`TRAIN_EVAL_SEED_BASE`.
DISTILL_SEED_BASE = 20_000
DISTILL_SEEDS_PER_RUN = 1000
#: Training seeds a distillation may use, its episodes staying below the held-out seeds.
DISTILL_TRAINING_SEEDS = range((TRAIN_EVAL_SEED_BASE - DISTILL_SEED_BASE) // DISTILL_SEEDS_PER_RUN)


def check_seeds(seeds) -> list[int]:
    """``seeds`` as a list, refused (``ValueError`` naming them) when one is not a
    non-negative whole number or appears twice: a seed run twice would be counted twice
    and narrow every interval."""
    seeds = list(seeds)
    bad = [s for s in seeds if isinstance(s, bool) or not isinstance(s, int) or s < 0]
    if bad:
        raise ValueError(f"seeds must be non-negative integers, got {', '.join(map(repr, bad))}")
    repeated = sorted({s for s in seeds if seeds.count(s) > 1})
    if repeated:
        raise ValueError(f"seeds must differ (each episode is counted once), got "
                         f"{', '.join(map(str, repeated))} more than once")
    if not seeds:
        raise ValueError("no seeds given")
    return seeds


def default_seeds(episodes: int) -> list[int]:
    """The frozen evaluation seeds: ``episodes`` seeds from :data:`EVAL_SEED_BASE`."""
    if episodes <= 0:
        raise ValueError(f"episodes must be positive, got {episodes}")
    return list(range(EVAL_SEED_BASE, EVAL_SEED_BASE + episodes))
