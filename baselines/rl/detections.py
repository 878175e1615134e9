"""A set encoder over the acoustic detections, for RL on ``AcousticTracking-v2`` ``measurements``.

The ``measurements`` observation is a padded set per band: K detections of the
source, its boundary ghosts and clutter in an order that carries no meaning, and
a mask. Two pieces turn it into something a Stable-Baselines3 PPO can learn on:

* :class:`~baselines.rl.detection_fixes.DetectionFixes`, an observation wrapper
  (``detection_fixes: true`` in the training config; ``train.py`` and the shipped agent
  apply it alike, :mod:`baselines.rl.detection_fixes`, which also computes it in JAX for
  the compiled PPO): every real detection fixed by the paper's least-squares positioner,
  a token per detection (its fix, the log standard deviations of its covariance, its log
  residual fit, a validity flag), and the tokens of the last step that had a valid fix
  held beside them with their age.
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

import torch
from gymnasium import spaces
from stable_baselines3.common.policies import MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from baselines.rl.config import ConfigError

# The front end lives beside its JAX twin; imported here under the names it had.
from baselines.rl.detection_fixes import (  # noqa: F401 (DetectionFixes: its old home)
    FIX_KEYS,
    OBS_KEYS,
    DetectionFixes,
    token_size,
)


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
        #: With a track (DetectionTrack's observation) its token joins the set.
        self.track = "track_fix" in observation_space.spaces
        self.embed = torch.nn.Sequential(
            torch.nn.Linear(token_size(q, self.track), embed_dim), torch.nn.ReLU(),
            torch.nn.Linear(embed_dim, embed_dim), torch.nn.ReLU(),
        )
        self.score = torch.nn.Linear(embed_dim, 1)
        self.summary = torch.nn.Sequential(torch.nn.Linear(embed_dim + 1, summary_dim),
                                           torch.nn.ReLU())
        self.register_buffer("bands", torch.eye(q).repeat_interleave(k, dim=0))

    def _tokens(self, observations: dict, prefix: str, held: float, age,
                one_hot: torch.Tensor, flag: float) -> tuple:
        fix = observations[f"{prefix}fix"].flatten(1, -2)  # (B, n, 3)
        batch, tokens = fix.shape[:2]
        valid = observations[f"{prefix}fix_valid"].reshape(batch, tokens) > 0.5
        columns = [held, age.reshape(batch, 1).expand(batch, tokens)]
        if self.track:
            columns += [flag, observations[f"{prefix}fix_deviation"].reshape(batch, tokens)]
        flags = torch.stack([torch.full((batch, tokens), c, dtype=fix.dtype, device=fix.device)
                             if isinstance(c, float) else c for c in columns], dim=-1)
        features = torch.cat([
            fix, observations[f"{prefix}fix_log_std"].flatten(1, -2),
            observations[f"{prefix}fix_log_fit"].reshape(batch, tokens, 1),
            one_hot.expand(batch, -1, -1), flags,
        ], dim=-1)
        return fix, valid, features

    def forward(self, observations: dict) -> torch.Tensor:
        age = observations["held_age"]
        parts = [self._tokens(observations, "", 0.0, torch.zeros_like(age), self.bands, 0.0),
                 self._tokens(observations, "held_", 1.0, age, self.bands, 0.0)]
        if self.track:
            parts.append(self._tokens(observations, "track_", 0.0, torch.zeros_like(age),
                                      torch.zeros_like(self.bands[:1]), 1.0))
        fix, valid, tokens_in = (torch.cat(group, dim=1) for group in zip(*parts,
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
