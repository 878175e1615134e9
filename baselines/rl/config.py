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

``cppo`` (:data:`COMPILED`) is the PPO compiled in JAX on the batched
environments (:mod:`baselines.rl.compiled`): its file ``cppo.yml`` has the
run keys :data:`COMPILED_RUN_KEYS` and the fields of :class:`CompiledSettings`.

Command-line overrides are ``key=value`` strings; dotted keys reach into
mappings (``policy_kwargs.net_arch=[64, 64]``). Values are parsed as Python
literals (:func:`ast.literal_eval`) or else as YAML scalars
(:func:`yaml.safe_load`), never evaluated as code
(:func:`baselines.parsing.parse_value`). Unknown keys and values of
the wrong type raise :class:`ConfigError` naming the valid choices.

Every numeric setting, run key or algorithm argument, has one row in
:data:`RANGES` (its type and allowed interval); :func:`validate` checks a
config against it before any environment is built, so a bad value is a
:class:`ConfigError` naming the key, the value and the range, never an
assertion inside Stable-Baselines3 or a run that trains into NaN.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import functools
import hashlib
import inspect
import json
import math
import re
from pathlib import Path
from typing import NamedTuple

import stable_baselines3
import yaml

import auv_envs
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
#: The environments the compiled PPO has a batched JAX version of (every family's).
COMPILED_ENV_IDS = tuple(entry.env_id for entry in auv_envs.FAMILIES)

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
    "detection_track": False,
    "marker_estimate": False,
    "marker_track": False,
    "nav_filter": False,
}
#: Types of the run keys that are not numbers (the numbers are rows of :data:`RANGES`).
_RUN_KEY_TYPES = {
    "obs_mode": str,
    "policy": str,
    "normalize": (bool, dict),
    "flatten_obs": bool,
    "env_kwargs": dict,
    "detection_fixes": bool,
    "detection_track": bool,
    "marker_estimate": bool,
    "marker_track": bool,
    "nav_filter": bool,
}
#: Run keys added after configs were first written, read with their defaults when absent.
_LATER_RUN_KEYS = ("detection_fixes", "detection_track", "marker_estimate", "marker_track",
                   "nav_filter")
#: The same for ``cppo``'s run keys (:data:`COMPILED_RUN_KEYS`).
_LATER_COMPILED_RUN_KEYS = ("marker_track", "detection_fixes", "detection_track",
                            "nav_filter")
#: Classical front ends a run key switches on (an observation wrapper each,
#: ``module:class``, applied by :func:`baselines.rl.envs.wrap_env` in this order).
FRONT_ENDS = {
    "detection_fixes": "baselines.rl.detection_fixes:DetectionFixes",
    "detection_track": "baselines.rl.detection_fixes:DetectionTrack",
    "marker_estimate": "baselines.rl.marker_estimate:MarkerEstimate",
    "marker_track": "baselines.rl.marker_track:MarkerTrack",
    "nav_filter": "baselines.rl.nav_filter:NavFilter",
}
#: How a shipped policy's description names each front end it reads through.
FRONT_END_WORDS = {"detection_fixes": "the detection fixes",
                   "detection_track": "the detection fixes and their Kalman track",
                   "marker_estimate": "ckf-pd's estimator",
                   "marker_track": "the marker tracker",
                   "nav_filter": "the navigation filter"}
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
#: Hyperparameters ``train.py --resume RUN --set KEY=VALUE`` may change (after a
#: divergence, say): they scale the later updates but not the shapes of the model, its
#: optimiser state, its buffers or its environments, so the checkpoint still fits.
RESUMABLE = ("learning_rate", "max_grad_norm", "clip_range")


#: Keys of ``cppo.yml`` that train.py reads itself, with their defaults: ``evals``
#: batched evaluations during the run; ``checkpoints`` writes the policy at each.
COMPILED_RUN_KEYS = {
    "obs_mode": "features",
    "n_timesteps": 1_500_000,
    "env_kwargs": {},
    "evals": 10,
    "checkpoints": False,
    "marker_track": False,
    "detection_fixes": False,
    "detection_track": False,
    "nav_filter": False,
}
#: Keys of a cppo run's ``env_kwargs`` (LARS ``control`` and ``time_limit``: its
#: ``control="position"`` policies; building the env checks them).
COMPILED_ENV_KWARGS = ("difficulty", "control", "time_limit")


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
    # The policy: SB3's MlpPolicy, JointResidualPolicy (a servo on the marker
    # tracker's observation, marker_track: true) with its servo's initial gain, or
    # DetectionSetPolicy (the set encoder over the acoustic detection fixes,
    # detection_fixes: true).
    policy: str = "MlpPolicy"
    servo_gain: float = 0.3
    log_std_init: float = 0.0
    # VecNormalize-style observation statistics (false: the observation as it is).
    normalize: bool = True
    # Memory: the width of an LSTM core under the policy's and the value's MLPs
    # (sb3-contrib's MlpLstmPolicy; 0: none, the policy sees one step).
    lstm_hidden_size: int = 0
    # The critic reads the privileged state (the env's state observation) during training;
    # the policy never does.
    privileged_critic: bool = False
    # Distillation (DAgger) instead of PPO: a privileged teacher of baselines.rl.teachers
    # labels every step the policy visits and the policy learns its actions ("": PPO).
    teacher: str = ""
    # The share of the run over which the teacher's own actions give way to the
    # policy's (DAgger's mixing probability, from 1 down to 0).
    teacher_fraction: float = 0.25
    # An auxiliary loss for a recurrent policy trained with the privileged state (a
    # privileged critic or a teacher): a linear head on the LSTM's output regresses the
    # privileged state (normalised), weighted by this coefficient, so that the memory
    # learns to estimate what it cannot see; training only, never exported (0: none).
    state_prediction_coef: float = 0.0


class ConfigError(ValueError):
    """A configuration problem, with a message that names the fix."""


_INTERVAL = re.compile(r"^([\[(])\s*([^,\s]+)\s*,\s*([^\])\s]+)\s*([\])])$")
_YAML_FLOAT_HINT = " (YAML reads 3e-4 as a string: write 3.0e-4)"


@dataclasses.dataclass(frozen=True)
class Range:
    """The values one numeric setting accepts: one row of :data:`RANGES`.

    Attributes:
        kind: ``int`` or ``float``. An integer is a valid float; ``true``/``false``
            are never numbers; a float must be finite (NaN and infinity are refused).
        interval: ``"[low, high]"``; a round bracket leaves that end out, ``inf`` is
            no bound.
        also: values accepted besides the interval (``-1`` for "all", ``None`` for "off").
        forms: strings accepted besides numbers, where the algorithm takes them
            (:func:`accepted_forms`): ``"lin_<x>"``, a schedule that decays linearly
            from ``x`` (in the interval) to 0; ``"auto"`` and ``"auto_<x>"``, SAC's
            learned coefficient (starting from ``x`` > 0, whose logarithm it learns).
        units: ``[n, unit]`` pairs accepted besides ``n`` alone (``train_freq``).
        note: why the bound is where it is, added to the error message.
    """

    kind: type
    interval: str
    also: tuple = ()
    forms: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    note: str = ""

    @functools.cached_property
    def bounds(self) -> tuple[float, float, bool, bool]:
        """``(low, high, low included, high included)``."""
        match = _INTERVAL.match(self.interval)
        if match is None:
            raise ValueError(f"not an interval: {self.interval!r}")
        left, low, high, right = match.groups()
        return float(low), float(high), left == "[", right == "]"

    def contains(self, x: float) -> bool:
        low, high, low_in, high_in = self.bounds
        return (low < x or (low_in and low == x)) and (x < high or (high_in and high == x))

    def _number_ok(self, value) -> bool:
        if isinstance(value, bool) or not isinstance(value, int | float):
            return False
        if self.kind is int and not isinstance(value, int):
            return False
        if isinstance(value, float) and not math.isfinite(value):
            return False
        return self.contains(value)

    def _form_ok(self, value: str, forms: tuple[str, ...]) -> bool:
        for form in forms:
            if value == form:
                return True
            prefix = form.removesuffix("<x>")
            if prefix != form and value.startswith(prefix):
                try:
                    x = float(value[len(prefix):])
                except ValueError:
                    return False
                if prefix == "auto_" and not x > 0:  # SAC learns log(x)
                    return False
                return math.isfinite(x) and self.contains(x)
        return False

    def accepts(self, value, forms: tuple[str, ...] | None = None) -> bool:
        """Whether ``value`` is allowed (``forms``: those of :attr:`forms` allowed here)."""
        if any(value is a or (type(value) is type(a) and value == a) for a in self.also):
            return True
        if isinstance(value, str):
            return self._form_ok(value, self.forms if forms is None else forms)
        if self.units and isinstance(value, list | tuple) and len(value) == 2 \
                and value[1] in self.units:
            value = value[0]
        return self._number_ok(value)

    def describe(self, forms: tuple[str, ...] = ()) -> str:
        """The accepted values in words, as error messages and docs/training.md give them."""
        kind = "an integer" if self.kind is int else "a finite number"
        text = kind if self.bounds[:2] == (-math.inf, math.inf) else f"{kind} in {self.interval}"
        alternatives = [repr(a) if a is not None else "None" for a in self.also]
        alternatives += [f"[n, {unit!r}]" for unit in self.units]
        for form in forms:
            if form.endswith("<x>"):
                where = "x > 0" if form.startswith("auto") else f"x in {self.interval}"
                alternatives.append(f"'{form}' ({where})")
            else:
                alternatives.append(repr(form))
        return " or ".join([text, *alternatives])

    def check(self, key: str, value, forms: tuple[str, ...] | None = None) -> None:
        """Raise :class:`ConfigError` naming ``key``, ``value`` and the range unless
        :meth:`accepts` it."""
        forms = self.forms if forms is None else forms
        if self.accepts(value, forms):
            return
        hint = ""
        if isinstance(value, str):
            with contextlib.suppress(ValueError):
                float(value)
                hint = _YAML_FLOAT_HINT
        note = f" ({self.note})" if self.note else ""
        raise ConfigError(f"{key} must be {self.describe(forms)}, got {value!r}{hint}{note}")


_AT_LEAST_1 = "[1, inf)"
#: Every numeric setting a YAML entry or ``--set`` may give, for every trainer: ``train.py``'s
#: run keys, the Stable-Baselines3 arguments of PPO, A2C, SAC, TD3 and DDPG, and the
#: compiled PPO's :class:`CompiledSettings` (a name means the same everywhere it occurs).
#: Dotted names reach into a mapping. :func:`validate` checks each value against its row;
#: ``tests/test_train_validation.py`` checks that every numeric argument has one.
RANGES = {
    # train.py's run keys
    "n_timesteps": Range(int, _AT_LEAST_1),
    "n_envs": Range(int, _AT_LEAST_1),
    "eval_freq": Range(int, _AT_LEAST_1),
    "n_eval_episodes": Range(int, f"[0, {EVAL_SEED_BASE - TRAIN_EVAL_SEED_BASE}]",
                             note="more would reach the leaderboard's evaluation seeds"),
    "checkpoint_freq": Range(int, _AT_LEAST_1),
    "keep_checkpoints": Range(int, _AT_LEAST_1),
    "torch_threads": Range(int, _AT_LEAST_1),
    "evals": Range(int, "[0, inf)"),  # cppo (0: no evaluation during the run)
    # the update: PPO, A2C, cppo (learning_rate, gamma, batch_size: all)
    "learning_rate": Range(float, "(0, inf)", forms=("lin_<x>",)),
    "n_steps": Range(int, _AT_LEAST_1),  # rollout length; SAC/TD3/DDPG: n-step returns
    "batch_size": Range(int, _AT_LEAST_1),
    "n_epochs": Range(int, _AT_LEAST_1),
    "gamma": Range(float, "[0, 1]"),
    "gae_lambda": Range(float, "[0, 1]"),
    "clip_range": Range(float, "(0, inf)", forms=("lin_<x>",)),
    "clip_range_vf": Range(float, "(0, inf)", also=(None,), forms=("lin_<x>",)),
    "ent_coef": Range(float, "[0, inf)", forms=("auto", "auto_<x>")),
    "vf_coef": Range(float, "[0, inf)"),
    "max_grad_norm": Range(float, "(0, inf)"),
    "target_kl": Range(float, "(0, inf)", also=(None,)),
    "sde_sample_freq": Range(int, _AT_LEAST_1, also=(-1,)),
    "stats_window_size": Range(int, _AT_LEAST_1),
    "rms_prop_eps": Range(float, "(0, inf)"),
    "num_envs": Range(int, _AT_LEAST_1),  # cppo
    "lstm_hidden_size": Range(int, "[0, 4096]"),  # cppo
    "teacher_fraction": Range(float, "[0, 1]"),  # cppo with a teacher
    "state_prediction_coef": Range(float, "[0, inf)"),  # cppo, recurrent and privileged
    "servo_gain": Range(float, "[0, inf)"),  # cppo JointResidualPolicy
    "log_std_init": Range(float, "[-20, 2]"),
    "n_minibatches": Range(int, _AT_LEAST_1),  # cppo
    # off-policy: SAC, TD3, DDPG
    "buffer_size": Range(int, _AT_LEAST_1),
    "learning_starts": Range(int, "[0, inf)"),
    "tau": Range(float, "(0, 1]"),
    "train_freq": Range(int, _AT_LEAST_1, units=("step", "episode")),
    "gradient_steps": Range(int, _AT_LEAST_1, also=(-1,)),
    "target_update_interval": Range(int, _AT_LEAST_1),
    "target_entropy": Range(float, "(-inf, inf)", forms=("auto",)),
    "policy_delay": Range(int, _AT_LEAST_1),
    "target_policy_noise": Range(float, "[0, inf)"),
    "target_noise_clip": Range(float, "[0, inf)"),
    "action_noise.sigma": Range(float, "[0, inf)"),
    # inside policy_kwargs
    "policy_kwargs.log_std_init": Range(float, "(-inf, inf)"),
}
#: ``action_noise: {type: <one of these>, sigma: <number>}`` (the classes:
#: :data:`baselines.rl.training.ACTION_NOISE`).
ACTION_NOISE_TYPES = ("normal", "ornstein-uhlenbeck")


def accepted_forms(algo: str, key: str, default) -> tuple[str, ...]:
    """The strings of ``RANGES[key].forms`` that ``algo`` takes for ``key``: schedules
    (``lin_``) in Stable-Baselines3 only (cppo's rate always decays to 0), ``auto`` where the
    argument's own default is a string (SAC's ``ent_coef`` and ``target_entropy``)."""
    if algo == COMPILED:
        return ()
    return tuple(f for f in RANGES[key].forms if f.startswith("lin_") or isinstance(default, str))


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
        if isinstance(data["run"], dict):  # keys added since
            later = _LATER_COMPILED_RUN_KEYS if data["algo"] == COMPILED else _LATER_RUN_KEYS
            for key in later:
                data["run"].setdefault(key, run_keys(data["algo"])[key])
        config = cls(**data)
        validate(config)
        return config

    def digest(self, ignore: tuple[str, ...] = ("n_timesteps",)) -> str:
        """SHA-256 of everything that changes what training computes.

        ``n_timesteps`` is left out by default so a finished run can be
        continued for longer; bookkeeping keys (evaluation and checkpoint
        frequencies) are left out because they do not change the learner.
        ``ignore`` names run keys or hyperparameters.
        """
        data = self.to_dict()
        for key in (*ignore, "eval_freq", "n_eval_episodes", "checkpoint_freq",
                    "keep_checkpoints"):
            data["run"].pop(key, None)
            data["hyperparams"].pop(key, None)
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()

    def resumable_digest(self) -> str:
        """:meth:`digest` without the settings a resumed run may change (:data:`RESUMABLE`):
        equal for every config that can continue the same checkpoint."""
        return self.digest(ignore=("n_timesteps", *RESUMABLE))


def resumed(config: TrainConfig, overrides: dict) -> TrainConfig:
    """``config`` with the :data:`RESUMABLE` settings in ``overrides`` changed, checked
    (``train.py --resume RUN --set learning_rate=1.0e-4``)."""
    others = sorted(set(overrides) - set(RESUMABLE))
    if others:
        raise ConfigError(f"a resumed run may change only {', '.join(RESUMABLE)} (anything "
                          f"else would not fit its checkpoint), got {', '.join(others)}")
    if config.algo == COMPILED:
        raise ConfigError("a compiled PPO (cppo) run cannot be resumed")
    changed = dataclasses.replace(config, hyperparams={**config.hyperparams, **overrides})
    validate(changed)
    return changed


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
    if algo == COMPILED:
        return dict(inspect.signature(CompiledSettings).parameters)
    params = inspect.signature(ALGORITHMS[algo].__init__).parameters
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


def _check_detection_front_end(policy: str, run: dict) -> None:
    """DetectionSetPolicy reads the detection fixes, with or without their track; the two
    front ends are one or the other."""
    if run["detection_fixes"] and run["detection_track"]:
        raise ConfigError("detection_track is the detection fixes with their track: set "
                          "detection_fixes: false with it")
    if policy == "DetectionSetPolicy" and not (run["detection_fixes"]
                                               or run["detection_track"]):
        raise ConfigError("DetectionSetPolicy reads the per-detection fixes: set "
                          "detection_fixes: true (or detection_track: true)")


def validate(config: TrainConfig) -> None:
    """Raise :class:`ConfigError` for anything train.py could not run.

    Every numeric value is checked against its row of :data:`RANGES`, then the
    relations between settings that Stable-Baselines3 asserts on (:func:`_check_relations`).
    """
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
    for key, value in config.run.items():
        if key in RANGES:
            RANGES[key].check(key, value)
            continue
        types = _RUN_KEY_TYPES[key]
        if isinstance(value, bool) and bool not in (types if isinstance(types, tuple)
                                                    else (types,)):
            raise ConfigError(f"{key} must be {_type_name(types)}, got {value!r}")
        if not isinstance(value, types):
            raise ConfigError(f"{key} must be {_type_name(types)}, got {value!r}")
    if config.run["policy"] not in POLICIES:
        raise ConfigError(f"unknown policy {config.run['policy']!r}; valid: {', '.join(POLICIES)}")
    if config.run["policy"] in CUSTOM_POLICIES and config.algo != "ppo":
        raise ConfigError(f"policy {config.run['policy']} is a PPO policy, not {config.algo}")
    _check_detection_front_end(config.run["policy"], config.run)
    if config.run["policy"] == "JointResidualPolicy":
        front_end = config.run["marker_estimate"] or config.run["marker_track"]
        if not front_end or config.run["normalize"] is not False:
            raise ConfigError("JointResidualPolicy reads a LARS front end's hold target as is: "
                              "set marker_estimate: true (or marker_track: true) and "
                              "normalize: false")
        _check_joint_targets(config.run["env_kwargs"])
    if not isinstance(config.seed, int) or isinstance(config.seed, bool):
        raise ConfigError(f"seed must be an integer, got {config.seed!r}")
    top = TRAIN_EVAL_SEED_BASE - config.run["n_envs"]
    if not 0 <= config.seed <= top:
        raise ConfigError(
            f"seed must be in [0, {top}] so training seeds stay below the held-out "
            f"evaluation seeds ({TRAIN_EVAL_SEED_BASE}+), got {config.seed}"
        )
    arguments = algo_arguments(config.algo)
    for key, value in config.hyperparams.items():
        if key not in arguments:
            raise ConfigError(
                f"unknown setting {key!r} for {config.algo}; "
                f"valid: {', '.join(sorted(set(arguments) | set(RUN_KEYS)))}"
            )
        _check_argument(config.algo, key, value, arguments[key].default)
    _check_relations(config, arguments)


def _check_relations(config: TrainConfig, arguments: dict[str, inspect.Parameter]) -> None:
    """What Stable-Baselines3 asserts on (or turns into NaN) across settings, once each
    value is in its range."""
    def setting(key):
        return config.hyperparams.get(key, arguments[key].default)

    n_envs = config.run["n_envs"]
    if config.algo in ("ppo", "a2c") and setting("normalize_advantage"):
        n_steps = setting("n_steps")
        if n_steps * n_envs < 2:
            raise ConfigError(f"n_steps x n_envs must be at least 2 with normalize_advantage "
                              f"(advantages are normalised over the rollout), got "
                              f"{n_steps} x {n_envs}")
        if config.algo == "ppo" and setting("batch_size") < 2:
            raise ConfigError(f"batch_size must be at least 2 with normalize_advantage "
                              f"(advantages are normalised over a minibatch), got "
                              f"{setting('batch_size')}")
    if config.algo in OFF_POLICY:
        train_freq = setting("train_freq")
        if isinstance(train_freq, list | tuple) and train_freq[1] == "episode" and n_envs > 1:
            raise ConfigError(f"train_freq in episodes needs n_envs 1, got {n_envs} "
                              "(count steps instead: train_freq: [n, step])")


def _check_joint_targets(env_kwargs: dict) -> None:
    if env_kwargs.get("control") != "position":
        raise ConfigError("JointResidualPolicy outputs joint targets: set "
                          "env_kwargs: {control: position}")


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
    modes = auv_envs.family(config.env_id).batched_modes
    if run["obs_mode"] not in modes:
        raise ConfigError(f"cppo trains {config.env_id} on obs_mode {modes}, got "
                          f"{run['obs_mode']!r}")
    kwargs = run["env_kwargs"]
    if not isinstance(kwargs, dict) or set(kwargs) - set(COMPILED_ENV_KWARGS):
        raise ConfigError(f"cppo env_kwargs may set {', '.join(COMPILED_ENV_KWARGS)} only, "
                          f"got {kwargs!r}")
    if kwargs.get("difficulty", "paper") not in LEVELS:
        raise ConfigError(f"difficulty must be one of {LEVELS}, got {kwargs['difficulty']!r}")
    for key in ("n_timesteps", "evals"):
        RANGES[key].check(key, run[key])
    for key in (key for key, default in COMPILED_RUN_KEYS.items() if isinstance(default, bool)):
        if not isinstance(run[key], bool):
            raise ConfigError(f"{key} must be true or false, got {run[key]!r}")
    if not isinstance(config.seed, int) or isinstance(config.seed, bool) \
            or not 0 <= config.seed < TRAIN_EVAL_SEED_BASE:
        raise ConfigError(f"seed must be an integer in [0, {TRAIN_EVAL_SEED_BASE}), "
                          f"got {config.seed!r}")
    fields = CompiledSettings._field_defaults
    for key, value in config.hyperparams.items():
        if key not in fields:
            raise ConfigError(f"unknown setting {key!r} for cppo; valid: "
                              f"{', '.join(sorted({*fields, *COMPILED_RUN_KEYS}))}")
        _check_argument(COMPILED, key, value, fields[key])
    settings = CompiledSettings(**config.hyperparams)
    if settings.policy not in ("MlpPolicy", "JointResidualPolicy", "DetectionSetPolicy"):
        raise ConfigError(f"cppo's policy is MlpPolicy, JointResidualPolicy or "
                          f"DetectionSetPolicy, got {settings.policy!r}")
    if settings.lstm_hidden_size:
        if settings.policy != "MlpPolicy":
            raise ConfigError(f"lstm_hidden_size gives MlpPolicy a memory; {settings.policy} "
                              "has none: set policy: MlpPolicy or lstm_hidden_size: 0")
        if settings.num_envs % settings.n_minibatches:
            raise ConfigError(f"a recurrent policy learns from whole rollouts of each env: "
                              f"num_envs ({settings.num_envs}) must split into n_minibatches "
                              f"({settings.n_minibatches}) equal groups")
    _check_detection_front_end(settings.policy, run)
    if settings.policy == "DetectionSetPolicy" and settings.normalize:
        raise ConfigError("DetectionSetPolicy reads the detection fixes as they are: set "
                          "normalize: false with it")
    if (run["detection_fixes"] or run["detection_track"]) and (
            config.env_id != "auv_envs/AcousticTracking-v2"
            or run["obs_mode"] != "measurements"):
        raise ConfigError("detection_fixes and detection_track are AcousticTracking-v2's "
                          "measurements front ends")
    if settings.policy == "JointResidualPolicy":
        if not run["marker_track"] or settings.normalize:
            raise ConfigError("JointResidualPolicy reads the marker tracker's hold target as "
                              "is: set marker_track: true and normalize: false")
        _check_joint_targets(kwargs)
    if run["marker_track"] and (config.env_id != "auv_envs/LARSCapture-v0"
                                or run["obs_mode"] != "features"):
        raise ConfigError("marker_track is LARSCapture-v0's features front end")
    if run["nav_filter"] and (config.env_id != "auv_envs/DockingMission-v0"
                              or run["obs_mode"] != "nav_features"):
        raise ConfigError("nav_filter is DockingMission-v0's nav_features front end")
    if (settings.num_envs * settings.n_steps) % settings.n_minibatches:
        raise ConfigError(f"num_envs x n_steps ({settings.num_envs} x {settings.n_steps}) must "
                          f"split into n_minibatches ({settings.n_minibatches}) equal parts")
    if settings.state_prediction_coef and not (
            settings.lstm_hidden_size and (settings.teacher or settings.privileged_critic)):
        raise ConfigError("state_prediction_coef trains a memory to predict the privileged "
                          "state: it needs lstm_hidden_size and a teacher or "
                          "privileged_critic: true")
    if settings.teacher:  # its name and env: baselines.rl.teachers.make_teacher
        if settings.privileged_critic:
            raise ConfigError("a teacher replaces the critic: set privileged_critic: false")


def _check_argument(algo: str, key: str, value, default) -> None:
    """One algorithm argument: its :data:`RANGES` row, else its type from its default;
    mappings and ``None`` defaults are checked by the algorithm when it is built, apart
    from their rows in :data:`RANGES` (``action_noise.sigma``)."""
    if key in RANGES:
        RANGES[key].check(key, value, accepted_forms(algo, key, default))
    elif isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{key} must be bool, got {value!r}")
    elif key == "action_noise":
        if value is not None and not (isinstance(value, dict) and set(value) == {"type", "sigma"}
                                      and value["type"] in ACTION_NOISE_TYPES):
            raise ConfigError(f"action_noise must be {{type: {'|'.join(ACTION_NOISE_TYPES)}, "
                              f"sigma: <number>}}, got {value!r}")
    elif key.endswith("_kwargs") and value is not None and not isinstance(value, dict):
        raise ConfigError(f"{key} must be a mapping, got {value!r}")
    for sub, item in (value.items() if isinstance(value, dict) else ()):
        if f"{key}.{sub}" in RANGES:
            RANGES[f"{key}.{sub}"].check(f"{key}.{sub}", item)


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
