"""The seed ranges: one definition, disjoint ranges, and every user reads it."""

from __future__ import annotations

import pytest

from baselines import seeds


def test_ranges_are_disjoint_and_ordered():
    low, high = seeds.TRAIN_SEED_RANGE
    assert 0 < low <= high < seeds.EVAL_SEED_BASE
    assert seeds.TRAIN_EVAL_SEED_BASE < seeds.EVAL_SEED_BASE
    assert seeds.default_seeds(3) == [seeds.EVAL_SEED_BASE + k for k in range(3)]
    with pytest.raises(ValueError, match="positive"):
        seeds.default_seeds(0)


def test_every_module_uses_the_one_definition():
    from baselines import evaluation
    from baselines.commands import evaluate
    from baselines.lars.training import siamese
    from baselines.rl import config, training

    assert evaluation.EVAL_SEED_BASE is seeds.EVAL_SEED_BASE
    assert evaluate.EVAL_SEED_BASE is seeds.EVAL_SEED_BASE
    assert evaluation.default_seeds is seeds.default_seeds
    assert config.TRAIN_EVAL_SEED_BASE is seeds.TRAIN_EVAL_SEED_BASE
    assert training.TRAIN_EVAL_SEED_BASE is seeds.TRAIN_EVAL_SEED_BASE
    assert siamese.TRAIN_SEED_RANGE is seeds.TRAIN_SEED_RANGE
