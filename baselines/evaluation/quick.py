"""The default run's design: a board that ranks, in minutes on two cores.

``python evaluate.py`` without ``--episodes``, ``--seeds`` or ``--agents`` runs this
design; every other run evaluates every chosen agent on every seed. Three choices,
each made by measurement (``docs/evaluation.md``, "The default run"):

* **Episodes where the ranks need them** (:data:`EPISODES`). A success rate near
  0 or 1 needs few episodes to be told from ``random`` (ten: 10/10 is [72 %, 100 %],
  0/10 is [0 %, 28 %]); a rate near one third, as the classical agents reach at
  ``hard``, needs about thirty to be told from zero (7/30 is [12 %, 40 %], 0/30 is
  [0 %, 11 %]); two high rates (93 % and 70 %) about ninety. Tracking tasks rank by
  RMSE and cost the most (a 30 s acoustic episode is 3,000 steps of a tracker).
* **A group's training seeds take the episodes in turn**: evaluation seed ``i`` goes
  to the group's ``i mod k``-th policy, so the pooled row still averages over its
  training seeds, each evaluation seed is played once, and a group costs what one
  agent costs. Every agent of a table plays the same evaluation seeds.
* **The agents of the full board only** (:data:`FULL_BOARD_ONLY`): superseded RL
  agents, a second observer, a second privileged reference, comparators and the
  stereo front end stay on the full board (``--episodes N`` or ``--all-agents``),
  each with its reason.

The seeds are the frozen evaluation seeds from 100000, as in every run, so the
default run's episodes are cached for (and reused by) a longer run.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from auv_envs.core.difficulty import DEFAULT_LEVEL
from baselines.evaluation.episodes import EpisodeTask

#: Episodes per table, by environment family and level, from the rates to be told apart
#: and what an episode costs (the published board's rates, 2 cores):
#:
#: * docking: at ``paper`` the agents dock nearly always or never (10 episodes); at
#:   ``hard`` the classical agent docks about a third of the time and must be told
#:   from zero and from the RL agent's ~80 % (30); an MPC episode costs 1-3 s.
#: * LARS: at ``hard`` the RL agent captures ~93 % and the classical pipeline ~70 %,
#:   which takes about 90 episodes a row to tell apart; an episode costs 0.05-0.3 s.
#: * acoustic tracking ranks by mean OSPA: at ``paper`` the best trackers (0.12 m RMSE)
#:   and the least-squares filter (0.16 m) differ by about one episode's spread, which
#:   takes about 20 episodes. At ``hard`` (10) RMSE's means rested on rare divergent
#:   episodes, which OSPA's cut-off bounds (``docs/evaluation.md``). An episode (30 s,
#:   3,000 steps of a tracker) costs 2-9 s.
#: * the docking mission: the privileged reference and the classical pipeline dock nearly
#:   always and the others never; at ``hard`` the classical pipeline docks about 60 %.
#:   Paired on the same seeds, a row beats ``random``'s 0/n at 5 % with 6 successes
#:   (McNemar: p = 2 / 2^6); 8 episodes leave the best row two failures to spare. An
#:   episode of up to 6,000 steps costs 0.2-6 s, but 3-72 s for the classical pipeline,
#:   whose time-outs at ``hard`` run its NMPC to the end (``docs/mission.md``).
EPISODES = {
    "auv_envs/DockingStation": {"easy": 10, "paper": 10, "hard": 30},
    "auv_envs/LampArrayDocking": {"easy": 10, "paper": 10, "hard": 30},
    "auv_envs/LARSCapture": {"easy": 10, "paper": 10, "hard": 90},
    "auv_envs/AcousticTracking": {"easy": 10, "paper": 20, "hard": 10},
    "auv_envs/DockingMission": {"easy": 8, "paper": 8, "hard": 8},
}
#: A family the table does not name (e.g. an environment registered later).
OTHER_EPISODES = {"easy": 10, "paper": 10, "hard": 30}
#: Agents (or groups) the default run leaves to the full board, and why.
FULL_BOARD_ONLY = {
    "ofnmpc-mhe": "the paper's second observer (ofnmpc-ekf ranks the pipeline); 1.5-3.5 s "
                  "an episode",
    "ofnmpc-state": "a second privileged reference (pd-state shows each level is solvable); "
                    "2 s an episode",
    "ltat-ckf-pd": "the stereo front end of ckf-pd (ckf-pd ranks the pipeline); 6-7 s an "
                   "episode",
    "gmphd-single": "a comparator of gmphd-gci (one sub-band)",
    "ppo-docking-features": "superseded by cppo-docking-features-hard",
    "ppo-lamp-array-features": "superseded by cppo-lamp-array-features-hard",
    "cppo-docking-features": "superseded by cppo-docking-features-hard (trained at hard, "
                             "better at both levels)",
    "cppo-lamp-array-features": "superseded by cppo-lamp-array-features-hard (trained at "
                                "hard, better at both levels)",
    "cppo-mission-nav-features": "superseded by cppo-mission-nav-filter (it docks; this "
                                 "one never does)",
    "cppo-acoustic-measurements": "superseded by cppo-acoustic-track (the same encoder with "
                                  "a track; better at paper and at hard)",
}


def episodes_for(env_id: str, env_kwargs: Mapping) -> int:
    """Episodes of the default run's table of ``env_id`` built with ``env_kwargs``."""
    level = dict(env_kwargs).get("difficulty", DEFAULT_LEVEL)
    family = env_id.rsplit("-v", 1)[0]
    return EPISODES.get(family, OTHER_EPISODES)[level]


def describe_episodes(levels: Sequence[str]) -> str:
    """The table sizes as words, from :data:`EPISODES`: ``"DockingStation 10 at paper and
    30 at hard, ..."`` (families with the same sizes together)."""
    by_sizes: dict[tuple[int, ...], list[str]] = {}
    for family, table in EPISODES.items():
        by_sizes.setdefault(tuple(table[level] for level in levels), []).append(
            family.split("/")[-1])
    parts = []
    for sizes, families in by_sizes.items():
        counts = " and ".join(f"{n} at {level}" for n, level in zip(sizes, levels,
                                                                     strict=True))
        parts.append(f"{' and '.join(families)} {counts}")
    return "; ".join(parts)


def max_episodes() -> int:
    """The most episodes any table of the default run plays (the seeds to plan)."""
    return max(n for table in (*EPISODES.values(), OTHER_EPISODES) for n in table.values())


def in_default_run(name: str, groups: Mapping[str, str]) -> bool:
    """Whether agent ``name`` (or its group) plays in the default run."""
    return name not in FULL_BOARD_ONLY and groups.get(name) not in FULL_BOARD_ONLY


def thin(tasks: Sequence[EpisodeTask], seeds: Sequence[int],
         groups: Mapping[str, str]) -> list[EpisodeTask]:
    """The default run's episodes among ``tasks`` planned on ``seeds``: the first
    :func:`episodes_for` seeds of each table, a group's ``i``-th seed to its
    ``i mod k``-th member (members in name order)."""
    position = {seed: i for i, seed in enumerate(seeds)}
    members: dict[str, list[str]] = {}
    for name in sorted({t.agent for t in tasks}):
        if name in groups:
            members.setdefault(groups[name], []).append(name)
    kept = []
    for task in tasks:
        i = position[task.seed]
        if i >= episodes_for(task.env_id, dict(task.env_kwargs)):
            continue
        group = members.get(groups.get(task.agent, ""), [task.agent])
        if task.agent in group and i % len(group) != group.index(task.agent):
            continue
        kept.append(task)
    return kept
