"""A docking policy from pixels, distilled from a ``features`` policy (teacher-student DAgger).

The student sees what a camera-only vehicle has: the forward camera's
``image`` (small, e.g. 84x63, rendered through the level's water) and the
INS/DVL ``velocity`` and ``attitude``. The teacher is a shipped ``features``
policy (e.g. ``cppo-docking-features-s0``) acting on the lamps the camera
sees, given exactly: the true lamp pixels the environment reports after each
step (``info["true_pixels"]``, ``info["true_visible"]``), scaled to the
teacher camera's resolution (the same camera, so the student's image must
keep its aspect ratio), with the same noisy sensors. Privileged information
enters only through the teacher's labels, as in asymmetric distillation.

DAgger (Ross, Gordon and Bagnell 2011, "A Reduction of Imitation Learning and
Structured Prediction to No-Regret Online Learning", AISTATS): round 0 rolls
out the teacher; in round ``r`` each step executes the teacher's action with
probability ``beta ** r`` and the student's otherwise, and every visited
frame is labelled with the teacher's action; after each round the student is
fitted to all frames so far (squared error of its deterministic action). The rules
(:func:`~baselines.rl.dagger.geometric_share`, :func:`~baselines.rl.dagger.taught`,
:func:`~baselines.rl.dagger.imitation_loss`) are :mod:`baselines.rl.dagger`'s, the
compiled trainer's distillation's on the batched envs: this module is their shell for
rendered images, which only the Gymnasium env draws.

The student is Stable-Baselines3's ``MultiInputPolicy`` (NatureCNN on the
image, an MLP on the sensors), saved as a PPO model, so the result is an
ordinary policy directory: ``evaluate.py --policy DIR`` ranks it, and
``--group`` pools training seeds on the leaderboard::

    python -m baselines.rl.distill --teacher cppo-docking-features-s0 \\
        --env DockingStation-v2 --difficulty paper --image-size 84 63 --seed 0 \\
        --out runs/pixels-s0
    python evaluate.py --policy runs/pixels-s0 --envs DockingStation-v2 --difficulty paper \\
        --seeds 300000-300019

Episode seeds come from :data:`baselines.seeds.DISTILL_SEED_BASE` (training
seeds, below :data:`baselines.seeds.TRAIN_EVAL_SEED_BASE`); the student is
evaluated after each round on the held-out training-evaluation seeds.
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import auv_envs  # noqa: F401  (registers the environments)
from auv_envs.core.assets import sha256_file
from auv_envs.core.difficulty import LEVELS
from baselines.rl import dagger
from baselines.rl.agents import load_policy_agent, policy_directory
from baselines.rl.envs import needs_rescale, wrap_env
from baselines.rl.manifest import (
    MANIFEST_FILE,
    MODEL_FILE,
    PolicyFileError,
    policies_root,
    read_manifest,
)
from baselines.rl.policy import PolicyAgent
from baselines.seeds import (
    DISTILL_SEED_BASE,
    DISTILL_SEEDS_PER_RUN,
    DISTILL_TRAINING_SEEDS,
    TRAIN_EVAL_SEED_BASE,
)

#: The sensors the student sees besides the image (both observation modes have them).
SENSORS = ("velocity", "attitude")


@dataclass(frozen=True)
class DistillSettings:
    """DAgger's settings."""

    rounds: int = 10
    episodes: int = 40  # per round
    beta: float = 0.5  # the teacher acts with probability beta ** round
    epochs: int = 4  # over all frames so far, after each round
    batch_size: int = 128
    learning_rate: float = 3e-4
    eval_episodes: int = 10  # held-out episodes of the student after each round


def teacher_observation(observation: dict, info: dict, scale: np.ndarray) -> dict:
    """The teacher's ``features`` observation at a student step: the lamps in view
    (``info["true_pixels"]``, zero where not visible) scaled by ``scale`` to the
    teacher camera's pixels, and the student's own noisy sensors."""
    visible = np.asarray(info["true_visible"], bool)
    pixels = np.where(visible[:, None], np.asarray(info["true_pixels"]) * scale, 0.0)
    return {"pixels": pixels.astype(np.float32), "visible": visible.astype(np.int8),
            **{key: observation[key] for key in SENSORS}}


def camera_scale(teacher_env: gym.Env, student_env: gym.Env) -> np.ndarray:
    """Teacher pixels per student pixel; ``ValueError`` unless both images have one aspect
    ratio (one camera: the same field of view)."""
    big = teacher_env.unwrapped.calibration.intrinsics
    small = student_env.unwrapped.calibration.intrinsics
    scale = np.array([big.width / small.width, big.height / small.height])
    if not np.isclose(scale[0], scale[1], rtol=1e-3):
        raise ValueError(f"the student's image ({small.width}x{small.height}) must keep the "
                         f"teacher camera's aspect ratio ({big.width}x{big.height}), e.g. "
                         f"84x63 for 640x480")
    return scale


class Student:
    """The pixel policy: an SB3 PPO ``MultiInputPolicy`` fitted by regression."""

    def __init__(self, env: gym.Env, seed: int, settings: DistillSettings):
        from stable_baselines3 import PPO

        if needs_rescale(env.action_space):
            raise ValueError(f"the student regresses the teacher's actions in the environment's "
                             f"units; {env.spec.id}'s actions are rescaled for learners")
        self.model = PPO("MultiInputPolicy", wrap_env(env.unwrapped), seed=seed, device="cpu")
        self.policy = self.model.policy
        # The mapping the shipped policy will act through (PolicyAgent), used here too.
        self.agent = PolicyAgent(env, self.model)
        self.settings = settings
        self.optimizer = torch.optim.Adam(self.policy.parameters(), lr=settings.learning_rate)

    def _mean(self, batch: dict) -> torch.Tensor:
        obs, _ = self.policy.obs_to_tensor(batch)
        features = self.policy.extract_features(obs, self.policy.pi_features_extractor)
        return self.policy.action_net(self.policy.mlp_extractor.forward_actor(features))

    def act(self, observation: dict) -> np.ndarray:
        """The deterministic action, mapped to the environment as a shipped policy's is."""
        observation = self.agent.learner_observation(observation)
        with torch.no_grad():
            batch = {k: v[None] for k, v in observation.items()}
            return self.agent.env_action(self._mean(batch)[0].numpy())

    def loss(self, frames: dict, labels: np.ndarray) -> float:
        """:func:`~baselines.rl.dagger.imitation_loss` of the deterministic action against
        ``labels`` over all frames (in parts of 512)."""
        with torch.no_grad():
            total = 0.0
            for start in range(0, len(labels), 512):
                part = {k: v[start:start + 512] for k, v in frames.items()}
                target = torch.as_tensor(labels[start:start + 512])
                total += float(dagger.imitation_loss(self._mean(part), target)) * len(target)
        return total / len(labels)

    def fit(self, frames: dict, labels: np.ndarray, rng: np.random.Generator) -> None:
        size = self.settings.batch_size
        for _ in range(self.settings.epochs):
            order = rng.permutation(len(labels))
            for start in range(0, len(order), size):
                index = np.sort(order[start:start + size])
                batch = {k: v[index] for k, v in frames.items()}
                loss = dagger.imitation_loss(self._mean(batch), torch.as_tensor(labels[index]))
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()


def rollout(env: gym.Env, teacher, student: Student, scale: np.ndarray, seed: int,
            share: float, rng: np.random.Generator) -> tuple[list, list, bool]:
    """One episode; the teacher acts with probability ``share`` at each step
    (:func:`~baselines.rl.dagger.taught`). Returns the student's observations, the teacher's
    actions at them, and the episode's success."""
    frames, labels = [], []
    observation, info = env.reset(seed=seed)
    while True:
        label = teacher.act(teacher_observation(observation, info, scale), info)
        frames.append(observation)
        labels.append(label)
        # the student is asked only where it acts (one CNN pass a step saved elsewhere)
        action = label if dagger.taught(rng.random(), share) else student.act(observation)
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return frames, labels, bool(info["episode_metrics"]["success"])


def student_success(env: gym.Env, student: Student, seeds) -> float:
    """The student's success rate alone on ``seeds``."""
    wins = 0
    for seed in seeds:
        observation, info = env.reset(seed=seed)
        while True:
            observation, _, terminated, truncated, info = env.step(student.act(observation))
            if terminated or truncated:
                break
        wins += bool(info["episode_metrics"]["success"])
    return wins / len(seeds)


def distill(teacher: str | Path, env_id: str, image_size: tuple[int, int], difficulty: str,
            seed: int, out: Path, settings: DistillSettings = DistillSettings(),
            group: str | None = None, command: str = "") -> dict:
    """Distil the ``features`` policy ``teacher`` (a name under ``assets/policies`` or a
    directory) into a pixel policy written to ``out``; returns its manifest."""
    teacher_dir = policy_directory(teacher if Path(teacher).is_dir()
                                   else policies_root() / str(teacher))
    teacher_manifest = read_manifest(teacher_dir)
    if teacher_manifest["obs_mode"] != "features":
        raise ValueError(f"the teacher must act on 'features', {teacher_dir} acts on "
                         f"{teacher_manifest['obs_mode']!r}")
    if teacher_manifest["env_id"] != env_id:
        raise ValueError(f"the teacher was trained on {teacher_manifest['env_id']}, not {env_id}")
    if settings.rounds * settings.episodes > DISTILL_SEEDS_PER_RUN:
        raise ValueError(f"rounds x episodes must stay within the seed's "
                         f"{DISTILL_SEEDS_PER_RUN} episodes")
    torch.manual_seed(seed)
    torch.set_num_threads(2)  # the shipped students were fitted so (the machine's 2 cores)
    teacher_env = gym.make(env_id, obs_mode="features")
    env = gym.make(env_id, obs_mode="image", image_size=tuple(image_size), difficulty=difficulty)
    try:
        return _distill(teacher_env, env, teacher_dir, image_size, difficulty, seed, out,
                        settings, group, command)
    finally:  # the image env holds a GL context
        env.close()
        teacher_env.close()


def _distill(teacher_env, env, teacher_dir: Path, image_size, difficulty: str, seed: int,
             out: Path, settings: DistillSettings, group: str | None, command: str) -> dict:
    scale = camera_scale(teacher_env, env)
    teacher_agent = load_policy_agent(teacher_dir, teacher_env)
    student = Student(env, seed, settings)
    rng = np.random.default_rng(seed)
    next_seed = DISTILL_SEED_BASE + DISTILL_SEEDS_PER_RUN * seed
    eval_seeds = range(TRAIN_EVAL_SEED_BASE, TRAIN_EVAL_SEED_BASE + settings.eval_episodes)
    frames: dict[str, list] = {key: [] for key in env.observation_space.spaces}
    labels: list = []
    curve = []
    start = time.perf_counter()
    for round_ in range(settings.rounds):
        beta = dagger.geometric_share(round_, settings.beta)
        wins = 0
        for _ in range(settings.episodes):
            obs, acts, success = rollout(env, teacher_agent, student, scale, next_seed, beta, rng)
            next_seed += 1
            wins += success
            for key in frames:
                frames[key].extend(o[key] for o in obs)
            labels.extend(acts)
        data = {key: np.stack(values) for key, values in frames.items()}
        targets = np.asarray(labels, np.float32)
        before = student.loss(data, targets)
        student.fit(data, targets, rng)
        row = {"round": round_, "beta": beta, "frames": len(targets),
               "rollout_success": wins / settings.episodes,
               "loss_before_fit": before, "loss_after_fit": student.loss(data, targets),
               "success_rate": student_success(env, student, eval_seeds),
               "wall_s": round(time.perf_counter() - start, 1)}
        curve.append(row)
        print(f"[round {round_}] beta {beta:.3f}: {row['frames']} frames, rollouts "
              f"{100 * row['rollout_success']:.0f} % docked, loss {before:.4f} -> "
              f"{row['loss_after_fit']:.4f}, student alone {100 * row['success_rate']:.0f} % "
              f"on {settings.eval_episodes} held-out episodes ({row['wall_s']} s)", flush=True)
    return write_policy(student, out, {
        "env_id": env.spec.id, "image_size": list(image_size), "difficulty": difficulty,
        "seed": seed, "teacher": teacher_dir.name, "frames": len(labels),
        "wall_time_s": round(time.perf_counter() - start, 1), "curve": curve,
        "settings": vars(settings), "group": group, "command": command})


def write_policy(student: Student, out: Path, run: dict) -> dict:
    """``out`` as a policy directory (``model.zip``, ``policy.json``, ``distill_curve.csv``)."""
    out.mkdir(parents=True, exist_ok=True)
    student.model.save(out / MODEL_FILE)
    with open(out / "distill_curve.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(run["curve"][0]))
        writer.writeheader()
        writer.writerows(run["curve"])
    w, h = run["image_size"]
    manifest = {
        "name": out.name, "algo": "ppo", "env_id": run["env_id"], "obs_mode": "image",
        "flatten_obs": False,
        "env_kwargs": {"image_size": run["image_size"], "difficulty": run["difficulty"]},
        "trainer": "baselines.rl.distill (DAgger from a features policy)",
        "teacher": run["teacher"], "seed": run["seed"], "n_timesteps": run["frames"],
        "wall_time_s": run["wall_time_s"], "settings": run["settings"],
        "command": run["command"], "curve": run["curve"],
        "description": f"CNN on {w}x{h} images, distilled (DAgger) from {run['teacher']}, "
                       f"at {run['difficulty']}",
        "files": {MODEL_FILE: sha256_file(out / MODEL_FILE)},
        **({"group": run["group"]} if run["group"] else {}),
    }
    (out / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--teacher", required=True,
                        help="a features policy: a name under assets/policies or a directory")
    parser.add_argument("--env", default="DockingStation-v2")
    parser.add_argument("--difficulty", default="paper", choices=LEVELS)
    parser.add_argument("--image-size", type=int, nargs=2, default=(84, 63), metavar=("W", "H"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--group", help="pool this policy with others of the group")
    defaults = DistillSettings()
    for field, value in vars(defaults).items():
        parser.add_argument(f"--{field.replace('_', '-')}", type=type(value), default=value)
    args = parser.parse_args(argv)
    settings = DistillSettings(**{f: getattr(args, f) for f in vars(defaults)})
    if min(settings.rounds, settings.episodes, settings.epochs, settings.batch_size,
           settings.eval_episodes) <= 0 or not 0.0 <= settings.beta <= 1.0:
        parser.error("rounds, episodes, epochs, batch size and eval episodes must be positive, "
                     "beta in [0, 1]")
    if args.seed not in DISTILL_TRAINING_SEEDS:
        parser.error(f"--seed must be in [0, {DISTILL_TRAINING_SEEDS.stop}) (its episodes stay "
                     f"below the held-out seeds)")
    command = " ".join(["python -m baselines.rl.distill", shlex.join(argv)])
    try:
        manifest = distill(args.teacher, f"auv_envs/{args.env}", tuple(args.image_size),
                           args.difficulty, args.seed, args.out, settings, args.group, command)
    except (ValueError, FileNotFoundError, PolicyFileError) as exc:
        parser.error(str(exc))
    print(f"wrote {args.out} ({manifest['wall_time_s']} s, {manifest['n_timesteps']} frames)")


if __name__ == "__main__":
    main()
