"""One Markdown page per environment id, written from the code's own declarations.

Nothing here restates an environment: every table is read from the registered
class and from an instance built per observation mode, so a page cannot drift
from the code. :func:`pages` returns ``{path: markdown}`` for ``docs/hooks.py``.

* the spaces: ``gym.make(id, obs_mode=mode)`` for every mode of ``obs_modes``,
  at the default sizes (building an env renders nothing; the image modes only
  allocate their renderer);
* ``reward_terms``, ``metric_keys``, ``difficulty_presets`` and ``metadata``:
  the class attributes the registry-driven tests read;
* the arguments: ``inspect.signature`` of the constructor;
* the versions: the family table (:data:`auv_envs.families.FAMILIES`: the superseded
  ids, the batched twin and its modes) and the registered ``max_episode_steps``;
* the picture: the entry of ``GALLERY`` in ``scripts/render_gallery.py`` that
  made an image under ``docs/images/``, if there is one;
* the description: the class docstring, through :mod:`rest_markdown`.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from rest_markdown import to_markdown

import auv_envs
from auv_envs.core.difficulty import LEVELS

REPO = Path(__file__).resolve().parent.parent
FOLDER = "env"


def page_path(env_id: str) -> str:
    """The page of ``env_id`` under ``docs/``: ``env/DockingStation-v2.md``."""
    return f"{FOLDER}/{env_id.split('/')[-1]}.md"


def pages() -> dict[str, str]:
    """``{path under docs/: Markdown}``: the overview and one page per id of
    :data:`auv_envs.ENVIRONMENTS`."""
    gallery = _gallery()
    out = {f"{FOLDER}/index.md": _overview(gallery)}
    for env_id in auv_envs.ENVIRONMENTS:
        out[page_path(env_id)] = _page(env_id, gallery.get(env_id))
    return out


# ---------------------------------------------------------------------- pages
def _overview(gallery: dict[str, dict]) -> str:
    lines = [
        "# Environments",
        "",
        "Every id that `import auv_envs` registers, one page each. The pages are written",
        "when the site is built, from the classes' own declarations (`obs_modes`,",
        "`reward_terms`, `metric_keys`, `difficulty_presets`, the constructor's",
        "signature), from an instance of each observation mode (the spaces) and from",
        "the class docstring, so they say what the code does.",
        "",
        "| picture | id | summary | obs modes | reward terms | steps |",
        "|---|---|---|---|---|---|",
    ]
    for env_id in auv_envs.ENVIRONMENTS:
        cls = auv_envs.task_class(env_id)
        name = env_id.split("/")[-1]
        picture = gallery.get(env_id)
        thumb = (f"![{name}](../images/{picture['file']}){{ width=\"160\" }}" if picture
                 else "–")
        lines.append(f"| {thumb} | [`{env_id}`]({name}.md) | {_summary(cls)} | "
                     f"{_codes(cls.obs_modes)} | {_codes(cls.reward_terms)} | "
                     f"{gym.spec(env_id).max_episode_steps} |")
    lines += [
        "",
        "The physics, sensors and scenes in more detail: [the environments report]"
        "(../environments.md); the levels: [difficulty](../difficulty.md).",
        "",
    ]
    return "\n".join(lines)


def _page(env_id: str, picture: dict | None) -> str:
    cls = auv_envs.task_class(env_id)
    name = env_id.split("/")[-1]
    spec = gym.spec(env_id)
    lines = [f"# {name}", "", _summary(cls), ""]
    lines += _facts(env_id, cls, spec)
    if picture:
        lines += _picture(picture)
    lines += ["## Description", "",
              "The class docstring (`help(env.unwrapped)`), as written in the code.", "",
              to_markdown(_body(cls.__doc__), _resolver(cls)), ""]
    lines += _observations(env_id, cls)
    lines += _rewards(cls)
    lines += _arguments(cls)
    lines += _levels(cls)
    lines += _versions(env_id, spec)
    return "\n".join(lines)


def _facts(env_id: str, cls: type, spec) -> list[str]:
    modes = ", ".join(f"`{m}`" + (" (default)" if m == _default_mode(cls) else "")
                      for m in cls.obs_modes)
    render = cls.metadata.get("render_modes") or []
    return [
        "| property | value |",
        "|---|---|",
        f"| id | `{env_id}` |",
        f"| class | `{cls.__module__}.{cls.__qualname__}` |",
        f"| observation modes | {modes} |",
        f"| difficulty levels | {_codes(cls.difficulty_presets)} |",
        f"| `max_episode_steps` (registered) | {spec.max_episode_steps} |",
        f"| render modes | {_codes(render) or 'none'} "
        f"({cls.metadata.get('render_fps', '-')} frames/s) |",
        "",
        "```python",
        "import gymnasium as gym",
        "import auv_envs  # registers the ids",
        "",
        f'env = gym.make("{env_id}", obs_mode="{_default_mode(cls)}", difficulty="paper")',
        "obs, info = env.reset(seed=0)",
        "```",
        "",
    ]


def _picture(picture: dict) -> list[str]:
    args = ", ".join(f"{k}={v!r}" for k, v in picture["kwargs"].items())
    return [
        f"![{picture['env_id']}](../images/{picture['file']})",
        "",
        f"`{picture['agent']}` on seed {picture['seed']}"
        + (f" ({args})" if args else "")
        + f", {picture['fraction']:.0%} of the way through the episode "
        "(`python scripts/render_gallery.py`). A clip of any agent: "
        f"`auv-record --env {picture['env_id'].split('/')[-1]} --agent {picture['agent']} "
        f"--seed {picture['seed']} --out videos` ([watching](../watching.md)).",
        "",
    ]


def _observations(env_id: str, cls: type) -> list[str]:
    lines = ["## Observation spaces", "",
             "Read from `env.observation_space` of `gym.make(id, obs_mode=mode)` at the "
             "default arguments.", "",
             "| mode | key | space | shape | dtype | bounds |",
             "|---|---|---|---|---|---|"]
    action = None
    for mode in cls.obs_modes:
        env = gym.make(env_id, obs_mode=mode)
        try:
            for key, space in _leaves(env.observation_space):
                lines.append(f"| `{mode}` | {f'`{key}`' if key else '-'} | "
                             f"`{type(space).__name__}` | {_shape(space)} | "
                             f"`{space.dtype}` | {_bounds(space)} |")
            action = env.action_space
        finally:
            env.close()
    lines += ["", "## Action space", "",
              "| space | shape | dtype | bounds |", "|---|---|---|---|",
              f"| `{type(action).__name__}` | {_shape(action)} | `{action.dtype}` | "
              f"{_bounds(action)} |", ""]
    return lines


def _rewards(cls: type) -> list[str]:
    lines = ["## Reward terms and metrics", "",
             "The reward is the sum of the terms of `reward_terms`, each reported as "
             "`info[\"reward_<term>\"]`; `metric_keys` are in `info` at every step.", "",
             "| reward term | `info` key |", "|---|---|"]
    lines += [f"| `{term}` | `reward_{term}` |" for term in cls.reward_terms]
    lines += ["", "Metrics: " + _codes(cls.metric_keys) + ".", ""]
    return lines


def _arguments(cls: type) -> list[str]:
    lines = ["## Arguments", "",
             f"`{cls.__name__}.__init__`, keyword by keyword (unknown keywords raise "
             "`TypeError`).", "",
             "| argument | default | type |", "|---|---|---|"]
    for parameter in inspect.signature(cls.__init__).parameters.values():
        if parameter.name == "self" or parameter.kind is parameter.VAR_KEYWORD:
            continue
        default = "" if parameter.default is parameter.empty else f"`{parameter.default!r}`"
        annotation = ("" if parameter.annotation is parameter.empty
                      else f"`{_escape(inspect.formatannotation(parameter.annotation))}`")
        lines.append(f"| `{parameter.name}` | {_escape(default)} | {annotation} |")
    return lines + [""]


def _levels(cls: type) -> list[str]:
    module = sys.modules[cls.__module__]
    lines = ["## Difficulty levels", "",
             "`difficulty_presets`: the keywords each level sets (a keyword given "
             "explicitly overrides the level's). For a parameter bundle, the fields "
             "that differ from the bundle's defaults.", "",
             "| level | keyword | value |", "|---|---|---|"]
    for level, preset in cls.difficulty_presets.items():
        if not preset:
            lines.append(f"| `{level}` | - | the released environment: every keyword "
                         "at its default |")
        for keyword, value in preset.items():
            constant = None if isinstance(value, int | float | str) else next(
                (n for n, v in vars(module).items() if v is value and n.isupper()), None)
            shown = _escape(_value(value))
            lines.append(f"| `{level}` | `{keyword}` | "
                         + (f"`{constant}`: " if constant else "") + f"{shown} |")
    return lines + [""]


def _versions(env_id: str, spec) -> list[str]:
    lines = ["## Versions", "",
             "| id | how to make it | `max_episode_steps` | differs by |",
             "|---|---|---|---|",
             f"| `{env_id}` | `gym.make` | {spec.max_episode_steps} | this page |"]
    entry = auv_envs.family(env_id)
    for old_id, kwargs in entry.previous.items():
        differs = ", ".join(f"`{k}={v!r}`" for k, v in kwargs.items())
        lines.append(f"| `{old_id}` | `gym.make` | {gym.spec(old_id).max_episode_steps} | "
                     f"superseded, still registered: {differs} |")
    lines.append(f"| `{entry.batched_id}` | `gym.make_vec(id, num_envs=N)` "
                 f"(`pip install -e \".[jax]\"`) | "
                 f"{gym.spec(entry.batched_id).max_episode_steps} | "
                 f"batched on JAX / MuJoCo MJX, obs modes {_codes(entry.batched_modes)}, "
                 f"levels {_codes(LEVELS)} ([tutorial](../tutorials/batched.md)) |")
    lines += ["", "The version history is in the class docstring above; the measurements "
              "behind each change are in the [changelog](../changelog.md).", ""]
    return lines


# ---------------------------------------------------------------------- declarations
def _gallery() -> dict[str, dict]:
    """env id -> its picture from ``GALLERY`` in ``scripts/render_gallery.py``, for the
    images that exist under ``docs/images/``."""
    source = REPO / "scripts" / "render_gallery.py"
    gallery = _module_constant(source, "GALLERY")
    out = {}
    for file, (env_id, kwargs, agent, seed, fraction) in gallery.items():
        if (REPO / "docs" / "images" / file).is_file():
            out.setdefault(env_id, dict(file=file, env_id=env_id, kwargs=kwargs, agent=agent,
                                        seed=seed, fraction=fraction))
    return out


def _module_constant(path: Path, name: str):
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name
                                                for t in node.targets):
            return ast.literal_eval(node.value)
    raise LookupError(f"{path} assigns no literal {name}")


# ---------------------------------------------------------------------- formatting
def _summary(cls: type) -> str:
    return inspect.cleandoc(cls.__doc__).split("\n\n", 1)[0].replace("\n", " ")


def _body(doc: str) -> str:
    """The docstring after its summary line."""
    return inspect.cleandoc(doc).split("\n\n", 1)[1]


def _default_mode(cls: type) -> str:
    return inspect.signature(cls.__init__).parameters["obs_mode"].default


def _resolver(cls: type):
    module = sys.modules[cls.__module__]

    def resolve(target: str) -> str:
        head, _, rest = target.partition(".")
        obj = getattr(module, head, None)
        if obj is None:
            return target
        full = (obj.__name__ if inspect.ismodule(obj)
                else f"{getattr(obj, '__module__', module.__name__)}."
                     f"{getattr(obj, '__qualname__', head)}")
        return f"{full}.{rest}" if rest else full

    return resolve


def _leaves(space: spaces.Space, prefix: str = ""):
    if isinstance(space, spaces.Dict):
        for key, sub in space.spaces.items():
            yield from _leaves(sub, f"{prefix}{key}" if not prefix else f"{prefix}.{key}")
    else:
        yield prefix, space


def _shape(space: spaces.Space) -> str:
    if isinstance(space, spaces.Discrete):
        return f"{space.n} values"
    return f"`{tuple(space.shape)}`"


def _bounds(space: spaces.Space) -> str:
    if isinstance(space, spaces.MultiBinary):
        return "{0, 1}"
    if isinstance(space, spaces.Discrete):
        return f"{space.start} .. {space.start + space.n - 1}"
    if isinstance(space, spaces.Box):
        low, high = np.asarray(space.low), np.asarray(space.high)
        if low.min() == low.max() and high.min() == high.max():
            return f"[{_number(low.flat[0])}, {_number(high.flat[0])}]"
        return (f"per element, in [{_number(low.min())}, {_number(high.max())}]"
                if low.size > 6 else
                f"[{', '.join(map(_number, low.ravel()))}] .. "
                f"[{', '.join(map(_number, high.ravel()))}]")
    return "-"


def _number(x) -> str:
    x = float(x)
    if np.isinf(x):
        return "-inf" if x < 0 else "inf"
    return f"{x:.4g}"


def _value(value, depth: int = 0) -> str:
    """A preset's value: a dataclass as its non-default fields, numbers to 4 digits."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        try:
            default = type(value)()
        except TypeError:
            default = None
        fields = [(f.name, getattr(value, f.name)) for f in dataclasses.fields(value)]
        changed = [(n, v) for n, v in fields
                   if default is None or not _equal(v, getattr(default, n))]
        inner = ", ".join(f"{n}={_value(v, depth + 1)}" for n, v in changed)
        return f"{type(value).__name__}({inner})" if depth else (
            f"`{type(value).__name__}({inner})`")
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, tuple):
        return "(" + ", ".join(_value(v, depth + 1) for v in value) + ")"
    return repr(value) if depth else f"`{value!r}`"


def _equal(a, b) -> bool:
    try:
        return bool(np.all(np.asarray(a) == np.asarray(b))) and type(a) is type(b)
    except Exception:  # noqa: BLE001 - unlike things are different
        return a is b


def _codes(names) -> str:
    return ", ".join(f"`{n}`" for n in names)


def _escape(text: str) -> str:
    return text.replace("|", r"\|")
