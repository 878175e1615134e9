"""DAgger's rules (baselines.rl.dagger), the ones both distilling shells execute."""

import jax.numpy as jnp
import numpy as np
import pytest
import torch

from baselines.rl import dagger


def test_linear_share_decays_from_one_to_zero_at_the_horizon():
    iterations = np.array([0, 5, 10, 20])
    np.testing.assert_allclose(dagger.linear_share(iterations, 10.0), [1.0, 0.5, 0.0, 0.0])
    np.testing.assert_allclose(dagger.linear_share(jnp.asarray(iterations), 10.0, jnp),
                               [1.0, 0.5, 0.0, 0.0])
    assert float(dagger.linear_share(0, 0.0)) == 0.0  # no horizon: the student throughout


def test_geometric_share_is_the_papers_beta_to_the_round():
    assert [dagger.geometric_share(r, 0.5) for r in range(4)] == [1.0, 0.5, 0.25, 0.125]
    assert dagger.geometric_share(3, 0.0) == 0.0 and dagger.geometric_share(0, 0.0) == 1.0
    with pytest.raises(ValueError, match="beta"):
        dagger.geometric_share(1, 1.5)


def test_mix_executes_the_teacher_below_its_share():
    teacher = np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    student = -teacher
    draws = np.array([0.1, 0.5, 0.9])
    np.testing.assert_array_equal(dagger.mix(teacher, student, draws, 0.5),
                                  [[1.0, 1.0], [-2.0, -2.0], [-3.0, -3.0]])
    np.testing.assert_array_equal(dagger.mix(teacher, student, draws, 1.0), teacher)
    np.testing.assert_array_equal(dagger.mix(teacher, student, draws, 0.0), student)
    np.testing.assert_array_equal(
        dagger.mix(jnp.asarray(teacher), jnp.asarray(student), jnp.asarray(draws), 0.5, jnp),
        dagger.mix(teacher, student, draws, 0.5))
    # One environment: a scalar draw picks the whole action.
    np.testing.assert_array_equal(dagger.mix(teacher[0], student[0], 0.3, 0.4), teacher[0])
    np.testing.assert_array_equal(dagger.mix(teacher[0], student[0], 0.7, 0.4), student[0])


def test_the_share_is_the_fraction_of_taught_steps():
    draws = np.random.default_rng(0).random(20_000)
    taught = dagger.mix(np.ones((20_000, 1)), np.zeros((20_000, 1)), draws, 0.3)
    assert abs(taught.mean() - 0.3) < 0.01


def test_imitation_loss_sums_the_entries_and_averages_the_steps_in_every_namespace():
    mean = np.array([[0.0, 1.0], [1.0, 1.0], [2.0, -1.0]], np.float32)
    label = np.array([[1.0, 1.0], [1.0, 3.0], [0.0, 0.0]], np.float32)
    expected = (1.0 + 4.0 + 5.0) / 3
    assert float(dagger.imitation_loss(mean, label)) == pytest.approx(expected)
    assert float(dagger.imitation_loss(jnp.asarray(mean), jnp.asarray(label))) \
        == pytest.approx(expected)
    assert float(dagger.imitation_loss(torch.as_tensor(mean), torch.as_tensor(label))) \
        == pytest.approx(expected)
