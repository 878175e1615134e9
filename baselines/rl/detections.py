"""A set encoder over the acoustic detections, for RL on ``AcousticTracking-v2`` ``measurements``.

The ``measurements`` observation is a padded set per band: K detections of the
source, its boundary ghosts and clutter in an order that carries no meaning, and
a mask. Two pieces turn it into something a Stable-Baselines3 PPO can learn on:

* :class:`DetectionFixes`, an observation wrapper (``detection_fixes: true`` in
  the training config; ``train.py`` and the shipped agent apply it alike): every
  real detection is fixed by the paper's least-squares positioner ([GMPHD]
  §1.1-1.3, :class:`~baselines.acoustic.perception.positioning.LeastSquaresPositioner`,
  fused TDOA-DOA rows, noise weighting, node dropouts honoured) from the
  measurements and the documented calibration, never from ``info``. Each
  detection becomes a token: its fix (in the learner's action units, [-1, 1]
  over the tank), the log10 standard deviations of the fix's covariance (m), the
  log of its residual ``chi2 / dof`` and a validity flag (real, finite, inside
  the tank, inside the residual gate). Beside them the wrapper holds the tokens
  of the last earlier step that had a valid fix, with their age: a frame stack
  of depth two that skips empty frames, so that the estimate survives steps
  without any fix (the ``hard`` level's dropouts). No clock calibration and no
  filter: the policy itself is feed-forward.
* :class:`DetectionSetExtractor`, a permutation-invariant features extractor
  (Deep Sets, Zaheer et al. 2017, with attention pooling): a shared MLP embeds
  each token with its band (one-hot), whether it is held and its age, a linear
  score over the embedding weighs the valid tokens (softmax over the set,
  masked), and the extractor outputs the
  weighted mean of the fixes followed by a summary of the set (the masked mean
  embedding and the share of valid tokens, through one layer).
* :class:`DetectionSetPolicy`, PPO's actor-critic whose mean action is that
  weighted mean fix. What PPO learns is which detections to trust and how far:
  the token embedding and the scores. The critic sees the same features.

Permuting the detections of a band does not change the features, nor do the
values in tokens that are not valid (``tests/test_rl_detections.py``).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.policies import MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from baselines.acoustic.perception.positioning import LeastSquaresPositioner
from baselines.rl.config import ConfigError

#: The observation keys :class:`DetectionFixes` writes.
FIX_KEYS = ("fix", "fix_log_std", "fix_log_fit", "fix_valid")
OBS_KEYS = (*FIX_KEYS, *(f"held_{key}" for key in FIX_KEYS), "held_age")
#: Floor on a fix's standard deviation and residual fit before their logarithms.
_LOG_FLOOR = 1e-6


class DetectionFixes(gym.ObservationWrapper):
    """Replaces the ``measurements`` observation by one least-squares fix per detection,
    with the fixes of the last step that had any held beside them.

    Observation (float32 unless stated; Q bands, K padded detections per band):
    ``fix`` (Q, K, 3) the fix in [-1, 1] units of the action space (the tank box,
    as ``RescaleAction`` maps it), ``fix_log_std`` (Q, K, 3) log10 of the square
    roots of the covariance's diagonal (m), ``fix_log_fit`` (Q, K) ln(chi2 / dof),
    ``fix_valid`` ``MultiBinary((Q, K))``. Tokens that are not valid fixes are zero.
    The same four under ``held_fix*`` are those of the latest earlier step with at least
    one valid fix (all zero before there was one), and ``held_age`` (1,) is how many
    steps ago that was, as ln(1 + steps). They carry the estimate across the steps
    without a valid fix (the ``hard`` level's node dropouts and fades) and let the
    policy weigh one step's fixes against the last: a frame stack of depth two that
    skips empty frames. :meth:`reset` (and :meth:`clear`) forget them.

    Raises:
        ConfigError: the environment is not an acoustic one in ``measurements`` mode.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        base = env.unwrapped
        if getattr(base, "obs_mode", None) != "measurements" or not hasattr(base,
                                                                            "calibration"):
            raise ConfigError("detection_fixes needs auv_envs/AcousticTracking-v2 with "
                              f"obs_mode='measurements', got {env.spec.id if env.spec else env}"
                              f" with obs_mode={getattr(base, 'obs_mode', None)!r}")
        self._positioner = LeastSquaresPositioner(base.calibration, method="fused")
        space = base.action_space
        self._low = space.low.astype(np.float64)
        self._span = (space.high - space.low).astype(np.float64)
        mask = env.observation_space["mask"]
        q, k = mask.shape
        tokens = {
            "fix": spaces.Box(-np.inf, np.inf, (q, k, 3), np.float32),
            "fix_log_std": spaces.Box(-np.inf, np.inf, (q, k, 3), np.float32),
            "fix_log_fit": spaces.Box(-np.inf, np.inf, (q, k), np.float32),
            "fix_valid": spaces.MultiBinary((q, k)),
        }
        self.observation_space = spaces.Dict({
            **tokens,
            **{f"held_{key}": space_ for key, space_ in tokens.items()},
            "held_age": spaces.Box(0.0, np.inf, (1,), np.float32),
        })
        self.clear()

    def clear(self) -> None:
        """Forget the held fixes (a new episode)."""
        self._held = None
        self._held_steps = 0

    def reset(self, **kwargs):
        self.clear()
        return super().reset(**kwargs)

    def _tokens(self, observation) -> dict:
        fixes = self._positioner.solve(
            observation["tdoa"], observation["azimuth"], observation["elevation"],
            observation["mask"], nodes=observation.get("node_mask"),
        )
        valid = fixes.valid
        position = np.where(valid[..., None], fixes.position, self._low + 0.5 * self._span)
        variance = np.diagonal(np.where(valid[..., None, None], fixes.covariance, 1.0),
                               axis1=-2, axis2=-1)
        fit = np.where(valid, fixes.chi2 / max(fixes.dof, 1), 1.0)
        log_std = 0.5 * np.log10(np.maximum(variance, _LOG_FLOOR ** 2))
        log_std[~valid] = 0.0
        return {
            "fix": (2.0 * (position - self._low) / self._span - 1.0).astype(np.float32),
            "fix_log_std": log_std.astype(np.float32),
            "fix_log_fit": np.log(np.maximum(fit, _LOG_FLOOR)).astype(np.float32),
            "fix_valid": valid.astype(np.int8),
        }

    def observation(self, observation):
        current = self._tokens(observation)
        if self._held is None:
            held = {key: np.zeros_like(value) for key, value in current.items()}
        else:
            held = self._held
        out = {**current, **{f"held_{key}": value for key, value in held.items()},
               "held_age": np.array([np.log1p(self._held_steps)], np.float32)}
        self._held_steps += 1
        if current["fix_valid"].any():
            self._held, self._held_steps = current, 1
        return out


class DetectionSetExtractor(BaseFeaturesExtractor):
    """Deep Sets with attention pooling over the tokens of :class:`DetectionFixes`.

    Output (``3 + summary_dim``): the attention-weighted mean fix (action units;
    zero when no token is valid), then the set summary.

    Args:
        observation_space: :class:`DetectionFixes`'s observation space.
        embed_dim: width of the shared token MLP (two layers, ReLU).
        summary_dim: width of the set summary.
    """

    def __init__(self, observation_space: spaces.Dict, embed_dim: int = 64,
                 summary_dim: int = 64):
        missing = set(OBS_KEYS) - set(getattr(observation_space, "spaces", {}))
        if missing:
            raise ConfigError(f"DetectionSetExtractor needs the observation keys of "
                              f"DetectionFixes (detection_fixes: true); missing {sorted(missing)}")
        super().__init__(observation_space, features_dim=3 + summary_dim)
        q, k = observation_space["fix_valid"].shape
        # fix (3), log std (3), log fit (1), band one-hot (q), held flag (1), log age (1)
        token_dim = 3 + 3 + 1 + q + 2
        self.embed = torch.nn.Sequential(
            torch.nn.Linear(token_dim, embed_dim), torch.nn.ReLU(),
            torch.nn.Linear(embed_dim, embed_dim), torch.nn.ReLU(),
        )
        self.score = torch.nn.Linear(embed_dim, 1)
        self.summary = torch.nn.Sequential(torch.nn.Linear(embed_dim + 1, summary_dim),
                                           torch.nn.ReLU())
        self.register_buffer("bands", torch.eye(q).repeat_interleave(k, dim=0))

    def _tokens(self, observations: dict, prefix: str, held: float, age) -> tuple:
        fix = observations[f"{prefix}fix"].flatten(1, 2)  # (B, Q*K, 3)
        batch, tokens = fix.shape[:2]
        valid = observations[f"{prefix}fix_valid"].reshape(batch, tokens) > 0.5
        flags = torch.stack([torch.full((batch, tokens), held, dtype=fix.dtype,
                                        device=fix.device),
                             age.reshape(batch, 1).expand(batch, tokens)], dim=-1)
        features = torch.cat([
            fix, observations[f"{prefix}fix_log_std"].flatten(1, 2),
            observations[f"{prefix}fix_log_fit"].reshape(batch, tokens, 1),
            self.bands.expand(batch, -1, -1), flags,
        ], dim=-1)
        return fix, valid, features

    def forward(self, observations: dict) -> torch.Tensor:
        age = observations["held_age"]
        now = self._tokens(observations, "", 0.0, torch.zeros_like(age))
        before = self._tokens(observations, "held_", 1.0, age)
        fix, valid, tokens_in = (torch.cat(pair, dim=1) for pair in zip(now, before,
                                                                         strict=True))
        h = self.embed(tokens_in)
        scores = self.score(h).squeeze(-1).masked_fill(~valid, -torch.inf)
        any_valid = valid.any(dim=1, keepdim=True)
        weights = torch.softmax(torch.where(any_valid, scores, torch.zeros_like(scores)), dim=1)
        weights = weights * valid  # all zero when nothing is valid
        pooled = (weights.unsqueeze(-1) * fix).sum(dim=1)
        count = valid.sum(dim=1, keepdim=True).to(h.dtype)
        mean_h = (h * valid.unsqueeze(-1)).sum(dim=1) / count.clamp(min=1.0)
        summary = self.summary(torch.cat([mean_h, count / valid.shape[1]], dim=-1))
        return torch.cat([pooled, summary], dim=-1)


class DetectionSetPolicy(MultiInputActorCriticPolicy):
    """PPO's actor-critic over :class:`DetectionSetExtractor` whose mean action is the
    attention-pooled fix itself: the actor has no layers of its own (``net_arch``
    ``pi: []``, no action layer), so every action it means is a convex combination of the
    valid fixes and what it learns is the weights. The critic (``vf``) reads the same
    features; the Gaussian's log standard deviations are learned as usual.

    (A linear correction on top of the pooled fix, tried first, made the estimate worse:
    Adam moves every weight by about the learning rate per update, about 0.05 m of action
    for 3e-4, and the updates' noise walked the correction away from zero.)
    """

    def __init__(self, observation_space, action_space, lr_schedule, **kwargs):
        if not isinstance(action_space, spaces.Box) or action_space.shape != (3,):
            raise ConfigError(f"DetectionSetPolicy acts with a 3-D position, got {action_space}")
        kwargs.setdefault("features_extractor_class", DetectionSetExtractor)
        net_arch = kwargs.setdefault("net_arch", {"pi": [], "vf": [64, 64]})
        if not isinstance(net_arch, dict) or net_arch.get("pi"):
            raise ConfigError("DetectionSetPolicy needs net_arch {pi: [], vf: [...]}: the "
                              f"actor reads the pooled fix directly, got {net_arch!r}")
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        self.action_net = torch.nn.Identity()  # the mean is the pooled fix (features[:3])
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1),
                                              **self.optimizer_kwargs)

    def _get_action_dist_from_latent(self, latent_pi: torch.Tensor):
        return self.action_dist.proba_distribution(latent_pi[..., :3], self.log_std)
