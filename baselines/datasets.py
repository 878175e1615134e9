"""Expert datasets: a registered agent's episodes as a Minari dataset, for offline RL and
imitation learning.

    python -m baselines.datasets record --agent NAME --env ID [--obs-mode MODE]
        [--episodes N] [--first-seed S] [--difficulty LEVEL] [--env-kwargs KEY=VALUE ...]
        [--out DIR] [--dataset-id ID] [--overwrite] [--jpeg]

Runs ``--episodes`` episodes of agent ``--agent`` (``python evaluate.py --list`` shows
where each applies) on the seeds from ``--first-seed`` (default
:data:`~baselines.seeds.DATASET_SEED_BASE`: training seeds, never the leaderboard's
evaluation seeds) and writes them as one Minari dataset under ``--out`` (Minari's
``MINARI_DATASETS_PATH``), with the id ``auv_envs/<env name>/<agent>-<obs
mode>-<difficulty>-v0`` unless ``--dataset-id`` names another. Read it back with
``MINARI_DATASETS_PATH=DIR`` and ``minari.load_dataset(ID)``.

Every episode of ``T`` steps holds, in Minari's layout:

* ``observations``: ``T + 1`` observations of the obs mode (a dict of arrays for the
  Dict modes), the reset's first;
* ``actions``: ``T`` actions as the environment applied them: clipped to the action
  space, as every ``auv_envs`` environment clips, in the space's dtype;
* ``rewards``, ``terminations``, ``truncations``: ``T`` each;
* ``infos``, ``T + 1`` entries per key, the reset's first: the environment's
  ``metric_keys`` and ``reward_<term>`` for each of its ``reward_terms``, as each
  step's info gave them (bool, int64 or float64 columns, arrays stacked; a key missing
  from a step is NaN); and ``infos["episode_metrics"][NAME]`` for each entry of the
  environment's ``info["episode_metrics"]``: NaN (strings: ``""``) but on the last
  entry, which holds the metric (numbers as float64 with ``None`` as NaN; strings as
  UTF-8, read back as bytes). :func:`episode_metrics` turns the last entry back into
  the environment's dict.

Each episode's seed is Minari's episode metadata
(``dataset.storage.get_episode_metadata([i])``); ``dataset.storage.metadata["auv_envs"]``
holds the recording's settings (environment id and arguments, agent, obs mode,
difficulty, seeds, the metrics' Python types). One environment and one agent run all
the episodes (``reset(seed)`` before each, the agents' protocol). Nothing appears under
``--out`` before every episode has run: they are written to a hidden temporary dataset
there, moved into place at the end and removed on a failure.

Minari's own ``DataCollector`` needs jax and the same info structure at every step; the
recorder needs neither: it builds each episode's buffer itself and writes it with
``minari.create_dataset_from_buffers``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import shutil
import sys
import tempfile
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import auv_envs
from auv_envs.core.difficulty import LEVELS
from auv_envs.extras import MissingExtra, one_line_errors, require
from baselines.commands.evaluate import resolve_env_ids
from baselines.evaluation import check_names, jsonable, resolve_env_kwargs
from baselines.registry import agent_spec, make_agent
from baselines.seeds import DATASET_SEED_BASE, EVAL_SEED_BASE, TRAIN_EVAL_SEED_BASE

#: Defaults of :func:`record_dataset` and the command line.
DEFAULT_EPISODES = 10
DEFAULT_DIFFICULTY = "paper"
#: Where the command line writes without ``--out`` or ``MINARI_DATASETS_PATH``.
DEFAULT_OUT = "results/datasets"
#: The key of the recording's settings in the dataset's metadata.
METADATA_KEY = "auv_envs"
#: Minari's environment variable for the datasets directory.
PATH_VARIABLE = "MINARI_DATASETS_PATH"

_MISSING = object()  # a key absent from a step's info
_METRIC_KINDS = ("bool", "int", "float", "str")


class RecordingError(RuntimeError):
    """An episode failed (the agent or the environment raised); nothing was written."""


def _minari():
    return require("minari", "datasets", "expert datasets (Minari)", "; Python 3.11+")


def default_dataset_id(env_id: str, agent: str, obs_mode: str, difficulty: str) -> str:
    """``auv_envs/<env name>/<agent>-<obs mode>-<difficulty>-v0`` (characters Minari's
    ids do not take become ``_``)."""
    name = re.sub(r"[^-\w]", "_", f"{agent}-{obs_mode}-{difficulty}")
    return f"auv_envs/{env_id.split('/', 1)[-1]}/{name}-v0"


def check_dataset_id(dataset_id: str) -> None:
    """Raise ``ValueError`` unless ``dataset_id`` is a Minari id with a version,
    ``[NAMESPACE/]NAME-vN``."""
    from minari.dataset.minari_dataset import parse_dataset_id

    try:
        parse_dataset_id(dataset_id)  # int(None) -> TypeError when the version is missing
    except (ValueError, TypeError):
        raise ValueError(f"a dataset id looks like NAMESPACE/NAME-vN (letters, digits, '-', "
                         f"'_'; NAMESPACE may hold '/'), got {dataset_id!r}") from None


@contextlib.contextmanager
def _datasets_path(path: Path):
    """Point Minari at ``path`` (it reads :data:`PATH_VARIABLE` on every call)."""
    previous = os.environ.get(PATH_VARIABLE)
    os.environ[PATH_VARIABLE] = str(path)
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop(PATH_VARIABLE, None)
        else:
            os.environ[PATH_VARIABLE] = previous


@contextlib.contextmanager
def _quiet_minari():
    """Minari warns about every metadata field left empty (author, e-mail, code link,
    evaluation env); the recording sets what it knows and leaves those out."""
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message=r"`(author|author_email|code_permalink|eval_env)` is set to None",
            category=UserWarning)
        yield


def _copy(obs):
    """A private copy of an observation (an env may reuse its arrays)."""
    if isinstance(obs, Mapping):
        return {key: _copy(value) for key, value in obs.items()}
    if isinstance(obs, tuple):
        return tuple(_copy(value) for value in obs)
    return np.array(obs, copy=True)


def _stack(items: list):
    """Observations of an episode -> the same structure of stacked arrays."""
    first = items[0]
    if isinstance(first, Mapping):
        return {key: _stack([item[key] for item in items]) for key in first}
    if isinstance(first, tuple):
        return tuple(_stack([item[i] for item in items]) for i in range(len(first)))
    return np.stack(items)


def _column(values: list, key: str):
    """One info key over an episode -> a column Minari stores with one type and shape.

    Strings (``""`` where missing) stay strings; complete bool and int columns keep
    their type; the rest become float64 arrays, with NaN for a missing entry or None.
    """
    present = [v for v in values if v is not _MISSING]
    complete = len(present) == len(values)
    if present and all(isinstance(v, str) for v in present):
        return ["" if v is _MISSING else v for v in values]
    if complete and all(isinstance(v, bool | np.bool_) for v in values):
        return np.array(values, dtype=bool)
    if complete and all(isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_)
                        for v in values):
        return np.array(values, dtype=np.int64)
    arrays = []
    for value in values:
        if value is _MISSING or value is None:
            arrays.append(None)
            continue
        try:
            arrays.append(np.asarray(value, dtype=np.float64))
        except (TypeError, ValueError):
            raise ValueError(f"info {key!r} holds {type(value).__name__} {value!r}: a dataset "
                             "records numbers, arrays of numbers and strings") from None
    shapes = {a.shape for a in arrays if a is not None}
    if len(shapes) > 1:
        raise ValueError(f"info {key!r} changes shape during the episode: {sorted(shapes)}")
    shape = shapes.pop() if shapes else ()
    return np.stack([np.full(shape, np.nan) if a is None else a for a in arrays])


def _metric_kind(value) -> str | None:
    if value is None:
        return None
    if isinstance(value, bool | np.bool_):
        return "bool"
    if isinstance(value, int | np.integer):
        return "int"
    if isinstance(value, str):
        return "str"
    return "float"


def _merge_kinds(kinds: dict[str, str | None], metrics: Mapping[str, Any]) -> None:
    """The Python type of each metric over the episodes so far (mixed types: float)."""
    for name, value in metrics.items():
        kind, known = _metric_kind(value), kinds.get(name)
        if known is None:
            kinds[name] = kind
        elif kind is not None and kind != known:
            kinds[name] = "float"


def _step_keys(env: gym.Env) -> list[str]:
    unwrapped = env.unwrapped
    keys = [*getattr(unwrapped, "metric_keys", ()),
            *(f"reward_{term}" for term in getattr(unwrapped, "reward_terms", ()))]
    return list(dict.fromkeys(keys))


def _record_episode(env: gym.Env, agent, seed: int, episode_id: int, step_keys: list[str]):
    """One seeded episode -> ``(EpisodeBuffer, episode metrics, return)``."""
    from minari.data_collector import EpisodeBuffer

    space = env.action_space
    obs, info = env.reset(seed=seed)
    agent.reset(seed)
    observations = [_copy(obs)]
    columns = {key: [info.get(key, _MISSING)] for key in step_keys}
    actions, rewards, terminations, truncations = [], [], [], []
    done = False
    while not done:
        action = agent.act(obs, info)
        obs, reward, terminated, truncated, info = env.step(action)
        if isinstance(space, gym.spaces.Box):  # as the env applied it (auv_envs clips)
            action = np.clip(np.asarray(action, dtype=np.float64), space.low,
                             space.high).astype(space.dtype)
        actions.append(_copy(action))
        observations.append(_copy(obs))
        rewards.append(float(reward))
        terminations.append(bool(terminated))
        truncations.append(bool(truncated))
        for key, column in columns.items():
            column.append(info.get(key, _MISSING))
        done = terminated or truncated
    metrics = dict(info.get("episode_metrics") or {})
    infos: dict[str, Any] = {key: _column(column, key) for key, column in columns.items()}
    if metrics:
        steps = len(rewards)
        infos["episode_metrics"] = {name: _column([_MISSING] * steps + [value], name)
                                    for name, value in metrics.items()}
    buffer = EpisodeBuffer(id=episode_id, seed=int(seed), observations=_stack(observations),
                           actions=_stack(actions), rewards=rewards, terminations=terminations,
                           truncations=truncations, infos=infos)
    return buffer, metrics, float(sum(rewards))


def _json_value(value):
    """``value`` as JSON data, or its repr when it is no data (a configuration object)."""
    value = jsonable(value)
    try:
        json.dumps(value)
    except (TypeError, ValueError):
        return repr(value)
    return value


def _install(staging: Path, root: Path, dataset_id: str, overwrite: bool) -> None:
    """Move the finished dataset from ``staging`` to ``root``; an old one is replaced
    only once the new one is in place (``overwrite``)."""
    from minari.dataset.minari_dataset import parse_dataset_id
    from minari.namespace import create_namespace, list_local_namespaces

    source, target = staging / dataset_id, root / dataset_id
    previous = None
    if target.exists():
        if not overwrite:
            raise FileExistsError(f"dataset {dataset_id} already exists in {root}")
        previous = staging / ".previous"
        os.replace(target, previous)
    try:
        namespace = parse_dataset_id(dataset_id)[0]
        with _datasets_path(root):
            if namespace is not None and namespace not in list_local_namespaces():
                create_namespace(namespace)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(source, target)
    except BaseException:
        if previous is not None and not target.exists():
            os.replace(previous, target)
        raise


def record_dataset(
    agent: str,
    env_id: str,
    obs_mode: str | None = None,
    episodes: int = DEFAULT_EPISODES,
    first_seed: int = DATASET_SEED_BASE,
    difficulty: str = DEFAULT_DIFFICULTY,
    out: str | os.PathLike | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    dataset_id: str | None = None,
    overwrite: bool = False,
    jpeg: bool = False,
    progress: Callable[[int, int, int, float, dict], None] | None = None,
):
    """Record ``episodes`` episodes of ``agent`` on ``env_id`` as a Minari dataset.

    Args:
        agent: a registered agent name.
        env_id: an environment id, or its name without ``auv_envs/``.
        obs_mode: the observation mode (default: the agent's default mode there).
        episodes: how many episodes, on seeds ``first_seed, first_seed + 1, ...``.
        first_seed: the first seed (default :data:`~baselines.seeds.DATASET_SEED_BASE`);
            seeds that reach :data:`~baselines.seeds.TRAIN_EVAL_SEED_BASE` are warned about.
        difficulty: the difficulty level (one of ``auv_envs.core.difficulty.LEVELS``).
        out: the datasets directory (Minari's ``MINARI_DATASETS_PATH``); default: Minari's
            (``$MINARI_DATASETS_PATH``, else ``~/.minari/datasets``).
        env_kwargs: further constructor arguments of the environment (not ``obs_mode``
            or ``difficulty``); the agent's required ones (``AgentSpec.env_kwargs``) are
            added.
        dataset_id: the Minari id (default :func:`default_dataset_id`).
        overwrite: replace an existing dataset of that id (once the new one is complete).
        jpeg: store image observations JPEG-encoded (lossy, far smaller) instead of raw.
        progress: ``progress(index, seed, steps, episode_return, episode_metrics)`` after
            each episode.

    Returns:
        The dataset, as ``minari.load_dataset`` reads it.

    Raises:
        ValueError: an unknown agent, environment or level; an agent that does not apply
            to the environment or obs mode; conflicting or rejected environment
            arguments; ``episodes < 1``; a negative seed; a malformed dataset id.
        FileExistsError: the dataset exists and ``overwrite`` is false.
        RecordingError: an episode raised (nothing is written).
        ImportError: Minari is not installed.
    """
    minari = _minari()
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    if isinstance(first_seed, bool) or not isinstance(first_seed, int) or first_seed < 0:
        raise ValueError(f"first_seed must be a non-negative integer, got {first_seed!r}")
    if difficulty not in LEVELS:
        raise ValueError(f"difficulty must be one of {', '.join(LEVELS)}, got {difficulty!r}")
    env_id = resolve_env_ids([env_id])[0]
    check_names([env_id], [])
    try:
        spec = agent_spec(agent)  # a group's name: its first training seed
    except KeyError as exc:
        raise ValueError(exc.args[0]) from exc
    reason = spec.skip_reason(env_id, obs_mode)
    if reason is not None:
        where = env_id if obs_mode is None else f"{env_id} in obs mode {obs_mode!r}"
        raise ValueError(f"agent {agent!r} does not apply to {where}: {reason}")
    obs_mode = obs_mode or spec.modes_for(env_id)[0]
    kwargs = dict(env_kwargs or {})
    for name in ("obs_mode", "difficulty"):
        if name in kwargs:
            raise ValueError(f"give {name} as an argument of its own, not in env_kwargs")
    conflicts = [k for k, v in kwargs.items() if k in spec.env_kwargs and spec.env_kwargs[k] != v]
    if conflicts:
        needs = ", ".join(f"{k}={spec.env_kwargs[k]!r}" for k in conflicts)
        got = ", ".join(f"{k}={kwargs[k]!r}" for k in conflicts)
        raise ValueError(f"agent {agent!r} needs {needs}, got {got}")
    kwargs = {**spec.env_kwargs, **kwargs}
    dataset_id = dataset_id or default_dataset_id(env_id, agent, obs_mode, difficulty)
    check_dataset_id(dataset_id)
    seeds = list(range(first_seed, first_seed + episodes))
    if seeds[-1] >= TRAIN_EVAL_SEED_BASE:
        warnings.warn(f"seeds {seeds[0]}-{seeds[-1]} reach {TRAIN_EVAL_SEED_BASE}, train.py's "
                      f"held-out evaluation episodes ({EVAL_SEED_BASE} and on: the "
                      "leaderboard's); a policy learnt from this dataset has seen them",
                      stacklevel=2)
    with contextlib.ExitStack() as cleanup:
        if out is None:
            root = Path(minari.storage.get_dataset_path()).absolute()
        else:
            root = Path(out).absolute()
        if (root / dataset_id).exists() and not overwrite:
            raise FileExistsError(f"dataset {dataset_id} already exists in {root}; "
                                  "overwrite=True (--overwrite) replaces it")
        try:
            env = gym.make(env_id, obs_mode=obs_mode, difficulty=difficulty, **kwargs)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{env_id} rejects arguments {kwargs}: {exc}") from exc
        cleanup.callback(env.close)
        actor = make_agent(agent, env)
        step_keys = _step_keys(env)
        missing = [parent for parent in (root, *root.parents) if not parent.exists()]
        root.mkdir(parents=True, exist_ok=True)
        for directory in reversed(missing):  # no empty directory left after a failure
            cleanup.callback(_remove_if_empty, directory)
        staging = Path(tempfile.mkdtemp(prefix=".recording-", dir=root))  # hidden from Minari
        cleanup.callback(shutil.rmtree, staging, ignore_errors=True)
        dataset, kinds = None, {}
        for index, seed in enumerate(seeds):
            try:
                buffer, metrics, episode_return = _record_episode(env, actor, seed, index,
                                                                  step_keys)
            except Exception as exc:
                raise RecordingError(f"episode {index} (seed {seed}) of {agent} on {env_id} "
                                     f"failed, nothing was written: "
                                     f"{type(exc).__name__}: {exc}") from exc
            _merge_kinds(kinds, metrics)
            with _datasets_path(staging), _quiet_minari():
                if dataset is None:
                    dataset = minari.create_dataset_from_buffers(
                        dataset_id, [buffer],
                        env=env.spec,
                        observation_space=env.observation_space,
                        action_space=env.action_space, algorithm_name=agent,
                        description=(f"{episodes} episodes of the {agent} agent "
                                     f"({spec.description}) on {env_id}, obs mode {obs_mode}, "
                                     f"difficulty {difficulty}, seeds {seeds[0]}-{seeds[-1]}"),
                        data_format="hdf5", jpeg_encoding=jpeg)
                else:
                    dataset.update_dataset_from_buffer([buffer])
            if progress is not None:
                progress(index, seed, len(buffer), episode_return, metrics)
        dataset.storage.update_metadata({METADATA_KEY: {
            "env_id": env_id,
            "agent": agent,
            "obs_mode": obs_mode,
            "difficulty": difficulty,
            "env_kwargs": {k: _json_value(v) for k, v in kwargs.items()},
            "first_seed": seeds[0],
            "episodes": episodes,
            "step_info_keys": step_keys,
            "episode_metric_types": {k: v or "float" for k, v in kinds.items()},
            "actions": "as applied: clipped to the action space, in its dtype",
            "auv_envs_version": auv_envs.__version__,
        }})
        _install(staging, root, dataset_id, overwrite)
        cleanup.pop_all()  # success: keep the directories
        shutil.rmtree(staging, ignore_errors=True)
        env.close()
    with _datasets_path(root):
        return minari.load_dataset(dataset_id)


def _remove_if_empty(directory: Path) -> None:
    with contextlib.suppress(OSError):
        directory.rmdir()


def episode_metrics(dataset, episode) -> dict:
    """The environment's ``info["episode_metrics"]`` of a recorded episode.

    Read from the last entry of ``episode.infos["episode_metrics"]``, with each
    metric's Python type from the dataset's metadata (bool, int, float, str); NaN
    comes back as ``None`` (as the leaderboard's files write it).
    """
    kinds = dataset.storage.metadata.get(METADATA_KEY, {}).get("episode_metric_types", {})
    result = {}
    for name, column in (episode.infos or {}).get("episode_metrics", {}).items():
        value = column[-1]
        if isinstance(value, bytes):
            value = value.decode("utf-8")
        elif isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, float) and math.isnan(value):
            value = None
        elif kinds.get(name) == "bool":
            value = bool(value)
        elif kinds.get(name) == "int":
            value = int(value)
        result[name] = value
    return result


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, description=__doc__.split("\n\n")[0].replace("\n", " "),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="\n\n".join(__doc__.split("\n\n")[1:3]))
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    record = commands.add_parser(
        "record", help="record an agent's episodes into a Minari dataset",
        description="Record an agent's episodes into a Minari dataset.")
    record.add_argument("--agent", required=True, metavar="NAME", help="a registered agent")
    record.add_argument("--env", required=True, metavar="ID",
                        help="environment id, or its name without 'auv_envs/'")
    record.add_argument("--obs-mode", default=None, metavar="MODE",
                        help="observation mode (default: the agent's default mode)")
    record.add_argument("--episodes", type=int, default=DEFAULT_EPISODES,
                        help=f"number of episodes (default {DEFAULT_EPISODES})")
    record.add_argument("--first-seed", type=int, default=DATASET_SEED_BASE,
                        help=f"seed of the first episode, the others follow (default "
                             f"{DATASET_SEED_BASE}: training seeds; the leaderboard "
                             f"evaluates from {EVAL_SEED_BASE})")
    record.add_argument("--difficulty", choices=LEVELS, default=DEFAULT_DIFFICULTY,
                        help=f"difficulty level (default {DEFAULT_DIFFICULTY})")
    record.add_argument("--env-kwargs", nargs="+", default=[], metavar="KEY=VALUE",
                        help="environment arguments (Python literals or bare strings), "
                             "e.g. time_limit=20")
    record.add_argument("--out", default=None, metavar="DIR",
                        help=f"datasets directory (default: ${PATH_VARIABLE} if set, else "
                             f"{DEFAULT_OUT})")
    record.add_argument("--dataset-id", default=None, metavar="ID",
                        help="Minari id NAMESPACE/NAME-vN (default "
                             "auv_envs/<env name>/<agent>-<obs mode>-<difficulty>-v0)")
    record.add_argument("--overwrite", action="store_true",
                        help="replace an existing dataset of that id")
    record.add_argument("--jpeg", action="store_true",
                        help="store image observations JPEG-encoded (lossy, far smaller)")
    return parser


def main(argv=None, prog: str = "python -m baselines.datasets") -> int:
    """The command line (a missing Minari is one line naming the extra)."""
    with one_line_errors(prog):
        return _main(argv, prog)


def _main(argv, prog: str) -> int:
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    out = args.out or os.environ.get(PATH_VARIABLE) or DEFAULT_OUT

    def report(index, seed, steps, episode_return, metrics):
        outcome = ("success" if metrics.get("success") else
                   metrics.get("failure_reason") or "no success")
        print(f"episode {index + 1}/{args.episodes} (seed {seed}): {steps} steps, "
              f"return {episode_return:.4g}, {outcome}", file=sys.stderr)

    try:
        env_id = resolve_env_ids([args.env])[0]
        check_names([env_id], [args.agent])
        env_kwargs = resolve_env_kwargs([env_id], args.env_kwargs)[env_id]
        dataset = record_dataset(
            args.agent, env_id, obs_mode=args.obs_mode, episodes=args.episodes,
            first_seed=args.first_seed, difficulty=args.difficulty, out=out,
            env_kwargs=env_kwargs, dataset_id=args.dataset_id, overwrite=args.overwrite,
            jpeg=args.jpeg, progress=report)
    except MissingExtra:
        raise  # one line: one_line_errors
    except (ValueError, KeyError, FileExistsError, ImportError) as exc:
        parser.error(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
    except RecordingError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {dataset.total_episodes} episodes ({dataset.total_steps} steps) as "
          f"{dataset.id} in {out}\nload it: {PATH_VARIABLE}={out} python -c "
          f"\"import minari; print(minari.load_dataset('{dataset.id}'))\"",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
