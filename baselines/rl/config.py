"""Training configuration: per-algorithm YAML hyperparameters, safe overrides, validation.

One YAML file per algorithm in ``baselines/rl/hyperparams/<algo>.yml`` maps an
environment id to its settings, with a ``default`` entry that every id starts
from (the layout of rl-baselines3-zoo's ``hyperparams/*.yml``). An entry mixes
two kinds of keys:

* run keys that ``train.py`` itself reads (:data:`RUN_KEYS`): ``obs_mode``,
  ``n_timesteps``, ``n_envs``, ``policy``, ``normalize``, ``flatten_obs``,
  ``env_kwargs``, ``eval_freq``, ``n_eval_episodes``, ``checkpoint_freq``,
  ``keep_checkpoints``, ``torch_threads``, and the classical front ends
  (:data:`FRONT_ENDS`): ``detection_fixes`` (the acoustic set encoder's
  per-detection fixes, :mod:`baselines.rl.detections`), ``marker_estimate``
  (``ckf-pd``'s LARS state estimate, :mod:`baselines.rl.marker_estimate`);
* keyword arguments of the Stable-Baselines3 algorithm (``learning_rate``,
  ``n_steps``, ``policy_kwargs`` ...), checked against its constructor.

``cppo`` (:data:`COMPILED`) is the PPO compiled in JAX on the batched docking
environments (:mod:`baselines.rl.compiled`): its file ``cppo.yml`` has the
run keys :data:`COMPILED_RUN_KEYS` and the fields of :class:`CompiledSettings`.

Command-line overrides are ``key=value`` strings; dotted keys reach into
mappings (``policy_kwargs.net_arch=[64, 64]``). Values are parsed as Python
literals (:func:`ast.literal_eval`) or else as YAML scalars
(:func:`yaml.safe_load`), never evaluated as code
(:func:`baselines.parsing.parse_value`). Unknown keys and values of
the wrong type raise :class:`ConfigError` naming the valid choices.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import hashlib
import inspect
import json
from pathlib import Path
from typing import NamedTuple

import stable_baselines3
import yaml

from baselines.fileio import atomic_write
from baselines.parsing import parse_value
from baselines.rl.manifest import ALGORITHM_NAMES
from baselines.seeds import EVAL_SEED_BASE, TRAIN_EVAL_SEED_BASE

#: Algorithm name (command line, YAML file name) -> Stable-Baselines3 class.
#: ``--algo`` name -> its Stable-Baselines3 class; the names are the manifests' (one list).
ALGORITHMS = {name: getattr(stable_baselines3, name.upper()) for name in ALGORITHM_NAMES}
OFF_POLICY = ("sac", "td3", "ddpg")
#: The compiled PPO (:mod:`baselines.rl.compiled`, ``pip install -e ".[jax]"``).
COMPILED = "cppo"
#: Every ``--algo`` train.py accepts.
TRAINERS = (*ALGORITHMS, COMPILED)
#: The environments the compiled PPO has a batched JAX version of.
COMPILED_ENV_IDS = ("auv_envs/DockingStation-v1", "auv_envs/LampArrayDocking-v1")

HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"

#: Keys ``train.py`` reads itself, with their defaults.
RUN_KEYS = {
    "obs_mode": "state",
    "n_timesteps": 100_000,
    "n_envs": 1,
    "policy": "auto",
    "normalize": False,
    "flatten_obs": False,
    "env_kwargs": {},
    "eval_freq": 10_000,
    "n_eval_episodes": 5,
    "checkpoint_freq": 10_000,
    "keep_checkpoints": 2,
    "torch_threads": 1,
    "detection_fixes": False,
    "marker_estimate": False,
}
_RUN_KEY_TYPES = {
    "obs_mode": str,
    "n_timesteps": int,
    "n_envs": int,
    "policy": str,
    "normalize": (bool, dict),
    "flatten_obs": bool,
    "env_kwargs": dict,
    "eval_freq": int,
    "n_eval_episodes": int,
    "checkpoint_freq": int,
    "keep_checkpoints": int,
    "torch_threads": int,
    "detection_fixes": bool,
    "marker_estimate": bool,
}
#: Run keys added after configs were first written, read with their defaults when absent.
_LATER_RUN_KEYS = ("detection_fixes", "marker_estimate")
#: Classical front ends a run key switches on (an observation wrapper each,
#: ``module:class``, applied by :func:`baselines.rl.envs.wrap_env` in this order).
FRONT_ENDS = {
    "detection_fixes": "baselines.rl.detections:DetectionFixes",
    "marker_estimate": "baselines.rl.marker_estimate:MarkerEstimate",
}
_POSITIVE = ("n_timesteps", "n_envs", "eval_freq", "checkpoint_freq", "keep_checkpoints",
             "torch_threads")
POLICIES = ("auto", "MlpPolicy", "CnnPolicy", "MultiInputPolicy", "DetectionSetPolicy",
            "JointResidualPolicy")
#: Policy names of this package's own policy classes (``module:class``, imported by
#: :class:`baselines.registry.LazyFactory`), PPO only.
CUSTOM_POLICIES = {"DetectionSetPolicy": "baselines.rl.detections:DetectionSetPolicy",
                   "JointResidualPolicy": "baselines.rl.marker_estimate:JointResidualPolicy"}

#: Constructor arguments train.py sets itself (or that name Python classes,
#: which a YAML file cannot hold safely).
_MANAGED = {
    "self", "policy", "env", "tensorboard_log", "verbose", "seed", "device",
    "_init_setup_model", "rollout_buffer_class", "replay_buffer_class",
}
#: Arguments that also accept a schedule string ``"lin_<initial value>"``.
_SCHEDULES = ("learning_rate", "clip_range", "clip_range_vf")


#: Keys of ``cppo.yml`` that train.py reads itself, with their defaults: ``evals``
#: batched evaluations during the run; ``checkpoints`` writes the policy at each.
COMPILED_RUN_KEYS = {
    "obs_mode": "features",
    "n_timesteps": 1_500_000,
    "env_kwargs": {},
    "evals": 10,
    "checkpoints": False,
}


class CompiledSettings(NamedTuple):
    """The compiled PPO's hyperparameters (SB3's names where they exist)."""

    num_envs: int = 256
    n_steps: int = 32
    n_minibatches: int = 32
    n_epochs: int = 5
    learning_rate: float = 3e-4  # decays linearly to 0, as train.py's lin_3.0e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5


class ConfigError(ValueError):
    """A configuration problem, with a message that names the fix."""


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """A fully resolved training configuration (what a run directory records).

    Attributes:
        algo: key of :data:`ALGORITHMS`.
        env_id: registered environment id.
        seed: training seed; vector env ``i`` is first reset with ``seed + i``.
        run: the run keys (:data:`RUN_KEYS`, all present).
        hyperparams: keyword arguments of the algorithm (YAML-safe values).
    """

    algo: str
    env_id: str
    seed: int
    run: dict
    hyperparams: dict

    def to_dict(self) -> dict:
        return {
            "algo": self.algo,
            "env_id": self.env_id,
            "seed": self.seed,
            "run": copy.deepcopy(self.run),
            "hyperparams": copy.deepcopy(self.hyperparams),
        }

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        if not isinstance(data, dict) or set(data) != {"algo", "env_id", "seed", "run",
                                                       "hyperparams"}:
            raise ConfigError(
                "a resolved config needs exactly the keys algo, env_id, seed, run, hyperparams"
            )
        data = copy.deepcopy(data)
        if data["algo"] != COMPILED and isinstance(data["run"], dict):  # keys added since
            for key in _LATER_RUN_KEYS:
                data["run"].setdefault(key, RUN_KEYS[key])
        config = cls(**data)
        validate(config)
        return config

    def digest(self, ignore: tuple[str, ...] = ("n_timesteps",)) -> str:
        """SHA-256 of everything that changes what training computes.

        ``n_timesteps`` is left out by default so a finished run can be
        continued for longer; bookkeeping keys (evaluation and checkpoint
        frequencies) are left out because they do not change the learner.
        """
        data = self.to_dict()
        for key in (*ignore, "eval_freq", "n_eval_episodes", "checkpoint_freq",
                    "keep_checkpoints"):
            data["run"].pop(key, None)
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def load_hyperparams(algo: str, hyperparams_dir: Path | None = None) -> dict:
    """The parsed YAML file of ``algo`` (a mapping of env id -> settings)."""
    if algo not in TRAINERS:
        raise ConfigError(f"unknown algorithm {algo!r}; valid: {', '.join(TRAINERS)}")
    path = Path(hyperparams_dir or HYPERPARAMS_DIR) / f"{algo}.yml"
    data = _read_yaml(path, "hyperparameter file")
    if not isinstance(data, dict) or not isinstance(data.get("default"), dict):
        raise ConfigError(f"{path} must map env ids to settings and have a 'default' entry")
    return data


def parse_overrides(items: list[str] | tuple[str, ...]) -> dict:
    """``["n_steps=64", "policy_kwargs.net_arch=[64,64]"]`` -> ``{dotted key: value}``.

    Values are read by :func:`baselines.parsing.parse_value` (a Python literal,
    else a YAML scalar); one it cannot read raises :class:`ConfigError`.
    """
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"an override must look like key=value, got {item!r}")
        try:
            out[key] = parse_value(value.strip())
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
    return out


def _deep_merge(base: dict, update: dict) -> dict:
    merged = copy.deepcopy(base)
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _deep_merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def algo_arguments(algo: str) -> dict[str, inspect.Parameter]:
    """The constructor arguments of ``algo`` a config may set (for ``cppo``, the fields
    of :class:`CompiledSettings`)."""
    params = inspect.signature(CompiledSettings if algo == COMPILED
                               else ALGORITHMS[algo].__init__).parameters
    return {k: p for k, p in params.items() if k not in _MANAGED}


def run_keys(algo: str) -> dict:
    """The run keys of ``algo``'s YAML entries, with their defaults."""
    return COMPILED_RUN_KEYS if algo == COMPILED else RUN_KEYS


def _set_dotted(settings: dict, key: str, value, valid: set[str], algo: str) -> None:
    head, *rest = key.split(".")
    if head not in valid:
        raise ConfigError(
            f"unknown setting {head!r} for {algo}; valid: {', '.join(sorted(valid))}"
        )
    target = settings
    path = [head, *rest]
    for part in path[:-1]:
        node = target.get(part)
        if node is None:
            node = target[part] = {}
        if not isinstance(node, dict):
            raise ConfigError(f"cannot set {key!r}: {part!r} is not a mapping")
        target = node
    target[path[-1]] = value


def resolve_config(
    algo: str,
    env_id: str,
    seed: int = 0,
    overrides: dict | None = None,
    hyperparams_dir: Path | None = None,
) -> TrainConfig:
    """``default`` entry, then the env's entry, then ``overrides`` -> a checked config.

    Args:
        algo: ``ppo``, ``sac``, ``td3``, ``a2c``, ``ddpg`` or ``cppo``.
        env_id: a registered id (``auv_envs/...``).
        seed: training seed.
        overrides: ``{dotted key: value}`` (see :func:`parse_overrides`).
        hyperparams_dir: where the YAML files are (default: the shipped ones).
    """
    table = load_hyperparams(algo, hyperparams_dir)
    settings = _deep_merge(table["default"], table.get(env_id) or {})
    defaults = run_keys(algo)
    valid = set(defaults) | set(algo_arguments(algo))
    for key in settings:
        if key not in valid:
            raise ConfigError(
                f"unknown setting {key!r} in {algo}.yml; valid: {', '.join(sorted(valid))}"
            )
    for key, value in (overrides or {}).items():
        _set_dotted(settings, key, value, valid, algo)
    run = {k: copy.deepcopy(settings.pop(k, default)) for k, default in defaults.items()}
    config = TrainConfig(algo=algo, env_id=env_id, seed=seed, run=run, hyperparams=settings)
    validate(config)
    return config


def _type_name(types) -> str:
    types = types if isinstance(types, tuple) else (types,)
    return " or ".join(t.__name__ for t in types)


def validate(config: TrainConfig) -> None:
    """Raise :class:`ConfigError` for anything train.py could not run."""
    import auv_envs

    if config.algo not in TRAINERS:
        raise ConfigError(f"unknown algorithm {config.algo!r}; valid: {', '.join(TRAINERS)}")
    if config.env_id not in auv_envs.ENVIRONMENTS:
        raise ConfigError(
            f"unknown env id {config.env_id!r}; registered: {', '.join(auv_envs.ENVIRONMENTS)}"
        )
    if config.algo == COMPILED:
        _validate_compiled(config)
        return
    missing = set(RUN_KEYS) - set(config.run)
    unknown = set(config.run) - set(RUN_KEYS)
    if missing or unknown:
        raise ConfigError(f"run keys missing {sorted(missing)} / unknown {sorted(unknown)}")
    for key, types in _RUN_KEY_TYPES.items():
        value = config.run[key]
        if isinstance(value, bool) and bool not in (types if isinstance(types, tuple)
                                                    else (types,)):
            raise ConfigError(f"{key} must be {_type_name(types)}, got {value!r}")
        if not isinstance(value, types):
            raise ConfigError(f"{key} must be {_type_name(types)}, got {value!r}")
    for key in _POSITIVE:
        if config.run[key] <= 0:
            raise ConfigError(f"{key} must be positive, got {config.run[key]}")
    if config.run["n_eval_episodes"] < 0:
        raise ConfigError("n_eval_episodes must be >= 0")
    if config.run["policy"] not in POLICIES:
        raise ConfigError(f"unknown policy {config.run['policy']!r}; valid: {', '.join(POLICIES)}")
    if config.run["policy"] in CUSTOM_POLICIES and config.algo != "ppo":
        raise ConfigError(f"policy {config.run['policy']} is a PPO policy, not {config.algo}")
    if config.run["policy"] == "DetectionSetPolicy" and not config.run["detection_fixes"]:
        raise ConfigError("DetectionSetPolicy reads the per-detection fixes: set "
                          "detection_fixes: true")
    if config.run["policy"] == "JointResidualPolicy":
        if not config.run["marker_estimate"] or config.run["normalize"] is not False:
            raise ConfigError("JointResidualPolicy reads MarkerEstimate's hold target as is: "
                              "set marker_estimate: true and normalize: false")
        if config.run["env_kwargs"].get("control") != "position":
            raise ConfigError("JointResidualPolicy outputs joint targets: set "
                              "env_kwargs: {control: position}")
    if not isinstance(config.seed, int) or isinstance(config.seed, bool):
        raise ConfigError(f"seed must be an integer, got {config.seed!r}")
    top = TRAIN_EVAL_SEED_BASE - config.run["n_envs"]
    if not 0 <= config.seed <= top:
        raise ConfigError(
            f"seed must be in [0, {top}] so training seeds stay below the held-out "
            f"evaluation seeds ({TRAIN_EVAL_SEED_BASE}+), got {config.seed}"
        )
    if config.run["n_eval_episodes"] > EVAL_SEED_BASE - TRAIN_EVAL_SEED_BASE:
        raise ConfigError("n_eval_episodes would reach the leaderboard's evaluation seeds")
    arguments = algo_arguments(config.algo)
    for key, value in config.hyperparams.items():
        if key not in arguments:
            raise ConfigError(
                f"unknown setting {key!r} for {config.algo}; "
                f"valid: {', '.join(sorted(set(arguments) | set(RUN_KEYS)))}"
            )
        _check_argument(key, value, arguments[key].default)


def _validate_compiled(config: TrainConfig) -> None:
    """:func:`validate` for ``cppo``: what the batched env and the compiled PPO can run."""
    from auv_envs.core.difficulty import LEVELS

    if config.env_id not in COMPILED_ENV_IDS:
        raise ConfigError(f"cppo trains the batched JAX envs only: {', '.join(COMPILED_ENV_IDS)}"
                          f" (got {config.env_id!r}); use ppo for the others")
    if set(config.run) != set(COMPILED_RUN_KEYS):
        raise ConfigError(f"cppo run keys must be {sorted(COMPILED_RUN_KEYS)}, "
                          f"got {sorted(config.run)}")
    run = config.run
    if run["obs_mode"] != "features":
        raise ConfigError(f"cppo trains on obs_mode 'features' only, got {run['obs_mode']!r}")
    kwargs = run["env_kwargs"]
    if not isinstance(kwargs, dict) or set(kwargs) - {"difficulty"}:
        raise ConfigError(f"cppo env_kwargs may set 'difficulty' only, got {kwargs!r}")
    if kwargs.get("difficulty", "paper") not in LEVELS:
        raise ConfigError(f"difficulty must be one of {LEVELS}, got {kwargs['difficulty']!r}")
    for key in ("n_timesteps", "evals"):
        if not isinstance(run[key], int) or isinstance(run[key], bool) or run[key] <= 0:
            raise ConfigError(f"{key} must be a positive integer, got {run[key]!r}")
    if not isinstance(run["checkpoints"], bool):
        raise ConfigError(f"checkpoints must be true or false, got {run['checkpoints']!r}")
    if not isinstance(config.seed, int) or isinstance(config.seed, bool) \
            or not 0 <= config.seed < TRAIN_EVAL_SEED_BASE:
        raise ConfigError(f"seed must be an integer in [0, {TRAIN_EVAL_SEED_BASE}), "
                          f"got {config.seed!r}")
    fields = CompiledSettings._field_defaults
    for key, value in config.hyperparams.items():
        if key not in fields:
            raise ConfigError(f"unknown setting {key!r} for cppo; valid: "
                              f"{', '.join(sorted({*fields, *COMPILED_RUN_KEYS}))}")
        if isinstance(value, str):  # no schedule strings: the rate always decays to 0
            raise ConfigError(f"{key} must be a number, got {value!r} (YAML reads 3e-4 as a "
                              "string: write 3.0e-4)")
        _check_argument(key, value, fields[key])
        if value < 0 or (isinstance(fields[key], int) and value == 0):
            sign = "positive" if isinstance(fields[key], int) else ">= 0"
            raise ConfigError(f"{key} must be {sign}, got {value!r}")
    settings = CompiledSettings(**config.hyperparams)
    if (settings.num_envs * settings.n_steps) % settings.n_minibatches:
        raise ConfigError(f"num_envs x n_steps ({settings.num_envs} x {settings.n_steps}) must "
                          f"split into n_minibatches ({settings.n_minibatches}) equal parts")


def _check_argument(key: str, value, default) -> None:
    if key in _SCHEDULES and isinstance(value, str):
        schedule_initial_value(key, value)
        return
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int) and key not in ("train_freq",):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    else:
        return  # None defaults, unions and mappings: checked by the algorithm itself
    if not ok:
        hint = ""
        if isinstance(value, str) and isinstance(default, float):
            hint = " (YAML reads 3e-4 as a string: write 3.0e-4)"
        raise ConfigError(
            f"{key} must be {type(default).__name__}, got {value!r}{hint}"
        )


def schedule_initial_value(key: str, text: str) -> float:
    """The initial value of a ``"lin_<value>"`` schedule string."""
    prefix = "lin_"
    if not text.startswith(prefix):
        hint = ""
        with contextlib.suppress(ValueError):
            float(text)
            hint = " (YAML reads 3e-4 as a string: write 3.0e-4)"
        raise ConfigError(
            f"{key} must be a number or 'lin_<initial value>', got {text!r}{hint}"
        )
    try:
        return float(text[len(prefix):])
    except ValueError as exc:
        raise ConfigError(f"{key}: cannot read the initial value of {text!r}") from exc


def save_config(config: TrainConfig, path: Path) -> None:
    """Write ``config`` as YAML, atomically (``resume`` rewrites it in a live run directory)."""
    atomic_write(path, yaml.safe_dump(config.to_dict(), sort_keys=False))


def read_config(path: Path) -> TrainConfig:
    """A config written by :func:`save_config`; clear errors when missing or corrupt."""
    return TrainConfig.from_dict(_read_yaml(Path(path), "config file"))


def _read_yaml(path: Path, what: str):
    """The parsed YAML at ``path``; :class:`ConfigError` naming ``what`` when it is
    missing or cannot be parsed."""
    if not path.is_file():
        raise ConfigError(f"{what} missing: {path}")
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{what} {path} is corrupt: {exc}") from exc
