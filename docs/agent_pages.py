"""The agents overview page, written from the agent registry (:mod:`baselines.registry`).

Every registered agent appears once, with a group's training seeds in one row, as
``python evaluate.py --list`` lists them: the catalogue's classical agents
(:data:`baselines.catalogue.AGENTS`) under their family's page, the shipped RL
policies under the RL page.
"""

from __future__ import annotations

import auv_envs
from baselines import catalogue, registry

#: The page of each environment family (the module of its entry point).
FAMILY_PAGES = {
    "auv_envs.tasks.docking.env": ("Docking", "docking.md"),
    "auv_envs.tasks.lars.env": ("LARS capture", "lars.md"),
    "auv_envs.tasks.acoustic.env": ("Acoustic tracking", "acoustic.md"),
}
RL_PAGE = ("RL agents", "rl.md")


def page() -> str:
    """``agents/index.md``."""
    classical = {spec.name for spec in catalogue.AGENTS}
    rows: dict[str, list] = {}
    for name in registry.agent_names():
        spec = registry.agent_spec(name)
        rows.setdefault(spec.group or name, []).append(spec)
    lines = [
        "# Agents",
        "",
        "Every agent keeps one protocol, `reset(seed)` then `act(observation, info) -> action`,",
        "and is looked up by name in the registry (`baselines.registry`). This table is",
        "written from the registry when the site is built; `python evaluate.py --list` prints",
        "the same. A group's training seeds share one row, and the leaderboard pools them.",
        "",
        "| agent | environments | obs modes | what it is | page |",
        "|---|---|---|---|---|",
    ]
    for key, specs in rows.items():
        spec = specs[0]
        title, link = (_family(spec) if spec.name in classical else RL_PAGE) or ("", "")
        seeds = (f" (seeds: {', '.join(f'`{s.name}`' for s in specs)})"
                 if spec.group else "")
        envs = ("all" if spec.env_ids is None
                else ", ".join(f"`{e.split('/')[-1]}`" for e in spec.env_ids))
        page_link = f"[{title}]({link})" if link else "-"
        lines.append(f"| `{key}`{seeds} | {envs} | "
                     f"{', '.join(f'`{m}`' for m in spec.obs_modes)} | "
                     f"{spec.description.replace('|', '/')}"
                     f"{' (heavy: left out of the default run)' if spec.heavy else ''} | "
                     f"{page_link} |")
    lines += [
        "",
        "The pages of each family give the equations of the paper it rebuilds, then the",
        "agents' own documentation from their docstrings. How to rank an agent of your own:",
        "[evaluate your own agent](../tutorials/evaluate.md).",
        "",
    ]
    return "\n".join(lines)


def _family(spec: registry.AgentSpec) -> tuple[str, str] | None:
    if spec.env_ids is None:
        return None
    modules = {auv_envs.ENVIRONMENTS[e].partition(":")[0] for e in spec.env_ids
               if e in auv_envs.ENVIRONMENTS}
    return FAMILY_PAGES.get(modules.pop()) if len(modules) == 1 else None
