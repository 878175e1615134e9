"""Rank every applicable agent on every environment over frozen evaluation seeds.

    python evaluate.py [--envs ID ...] [--agents NAME ...] [--obs-modes MODE ...]
                       [--episodes N] [--seeds A-B] [--env-kwargs [ENV:]KEY=VALUE ...]
                       [--out DIR] [--backend local|ray] [--ray-address ADDR] [--workers N]

Installed, the same command is ``auv-evaluate``. Writes
``leaderboard.{md,csv,json,html}``, ``plots/*.png``, ``skipped.json`` and
``episodes.json`` under ``--out`` and prints one compact Markdown table per
environment (``--verbose``: every column and the skipped pairs). Each cell is a
mean with its 95 % interval; agents are ranked by success rate (tracking: mean OSPA),
and a row's rank is one more than the number of rows that beat it significantly (on
the same seeds by a paired permutation test of the per-seed difference at 5 %).
A run merges into the board already in ``--out`` (``board.json``): the rows it
evaluates are replaced, the others kept, so the page always shows one whole
board (``--new-board`` starts afresh). Finished episodes are cached under
``--out``/episodes (one file each), so a
rerun, or a run after an interruption, only runs what is missing. The cache
key includes a fingerprint of the package code and assets, so episodes of
edited agents or environments run again.

Default run (the README's main command), the quick board
(:mod:`baselines.evaluation.quick`): every environment at the ``paper`` and ``hard``
difficulty levels (``DEFAULT_LEVELS``), every registered agent in its default obs
mode except the heavy ones (``AgentSpec.heavy``: the image front ends, about a minute
an episode; ``--all-agents`` adds them) and those of the full board only
(``quick.FULL_BOARD_ONLY``: superseded, second or comparator agents), on the frozen
seeds from 100000, each table as many episodes as it needs to rank its agents
(``quick.EPISODES``), a group's training seeds taking the seeds in turn; each
environment's default arguments except the acoustic episodes, shortened to 30 s
(``DEFAULT_ENV_KWARGS``), on min(4, CPUs) local worker processes.
``--episodes N`` (or ``--seeds``) runs the full board instead: N episodes for every
agent and every training seed of a group, every agent but the heavy ones.
``--design quick --seeds A-B`` runs the quick board on other seeds (each table its
first seeds of those).
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import signal
import sys
import textwrap
import threading
from pathlib import Path

import auv_envs
from auv_envs.core.difficulty import LEVELS
from auv_envs.extras import one_line_errors, require
from auv_envs.record import check_speed, parse_size
from baselines import leaderboard
from baselines.evaluation import (
    BACKENDS,
    POLICY_PREFIX,
    VideoSpec,
    board,
    bound_rows,
    check_names,
    env_parameters,
    evaluate_all,
    import_agent_modules,
    quick,
    resolve_env_kwargs,
    summarise,
)
from baselines.registry import (
    agent_groups,
    agent_names,
    agent_spec,
    env_obs_modes,
    group_members,
    resolve_agent_names,
)
from baselines.seeds import EVAL_SEED_BASE, check_seeds, default_seeds

#: Environment arguments of the default run; ``--env-kwargs`` overrides them
#: key by key. The acoustic episodes are 60 s (6000 steps) by default, which
#: makes the GM-PHD trackers the bulk of the run; 30 s keeps the default run
#: to a few minutes on 2 cores.
DEFAULT_ENV_KWARGS = {"auv_envs/AcousticTracking-v2": {"time_limit": 30.0}}
#: Difficulty levels of the default run (``--difficulty``): the papers' water and beyond.
DEFAULT_LEVELS: tuple[str, ...] = ("paper", "hard")


def default_workers() -> int:
    return max(1, min(4, os.cpu_count() or 1))


def parse_seeds(text: str) -> list[int]:
    """``--seeds``: ``"A-B"`` (inclusive) or ``"A,B,C"`` -> list of seeds, each a
    non-negative integer given once (:func:`baselines.seeds.check_seeds`)."""
    text = text.strip()
    form = f"seeds look like 'A-B' or 'A,B,C' (non-negative integers), got {text!r}"
    if re.fullmatch(r"\d+\s*-\s*\d+", text):
        first, last = (int(x) for x in text.split("-"))
        if last < first:
            raise ValueError(f"--seeds {text}: the range is reversed; did you mean "
                             f"{last}-{first}?")
        return list(range(first, last + 1))
    try:
        seeds = [int(x) for x in text.split(",")]
    except ValueError as exc:
        raise ValueError(form) from exc
    return check_seeds(seeds)


def resolve_env_ids(names) -> list[str]:
    """Full ids for names given as ids or as the part after ``auv_envs/``."""
    short = {env_id.split("/", 1)[-1]: env_id for env_id in auv_envs.ENVIRONMENTS}
    return [short.get(name, name) for name in names]


def _keys(group) -> set[str]:
    """The keywords a ``--env-kwargs`` group sets (``[ENV:]KEY=VALUE`` texts)."""
    return {text.partition("=")[0].rpartition(":")[2].strip() for text in group}


def scenario_groups(groups, scenario: str | None, difficulty) -> list[list[str]]:
    """The ``--env-kwargs`` groups with ``--scenario`` and ``--difficulty`` added.

    A keyword is set in one place only: a group that sets ``scenario=`` or
    ``difficulty=`` beside the dedicated option is refused (``ValueError`` naming
    both). Without ``--difficulty``, a group that sets no ``difficulty=`` runs at
    each of :data:`DEFAULT_LEVELS` and one that sets it runs at its own level.
    """
    out = []
    for group in groups:
        keys = _keys(group)
        for option, value, key in (("--scenario", scenario, "scenario"),
                                   ("--difficulty", difficulty, "difficulty")):
            if value and key in keys:
                raise ValueError(f"--env-kwargs {' '.join(group)} and {option} both set "
                                 f"{key}; give it once")
        if scenario:
            group = [*group, f"scenario={scenario}"]
        if "difficulty" in keys:
            out.append(list(group))
            continue
        levels = DEFAULT_LEVELS if difficulty is None else difficulty
        out.extend([*group, f"difficulty={level}"] for level in dict.fromkeys(levels))
        if not levels:
            out.append(list(group))
    return out


def default_agents(env_ids, quick_board: bool = False) -> tuple[list[str], list[str]]:
    """``(agents, left_out)``: the registered agents of a run that names none, and those
    it leaves out that apply to one of ``env_ids``: the heavy ones
    (:attr:`AgentSpec.heavy`) and, on the quick board, those of the full board only
    (:data:`baselines.evaluation.quick.FULL_BOARD_ONLY`; a group by its name)."""
    agents, left_out = [], []
    groups = agent_groups()
    for name in agent_names():
        spec = agent_spec(name)
        if not spec.heavy and (not quick_board or quick.in_default_run(name, groups)):
            agents.append(name)
        elif spec.env_ids is None or set(spec.env_ids) & set(env_ids):
            left_out.append(groups.get(name, name))
    return agents, list(dict.fromkeys(left_out))


def plain_text(text: str) -> str:
    """A docstring's reST markup as a terminal shows text: ````x```` and
    ``:role:`x``` as ``x``."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", text)
    return re.sub(r"``([^`]+)``", r"\1", text)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=plain_text("\n\n".join(__doc__.split("\n\n")[2:]))
        + "\n\n" + textwrap.fill("Episodes a table in the default run: "
                                 f"{quick.describe_episodes(DEFAULT_LEVELS)}.", 84),
    )
    parser.add_argument("--envs", nargs="+", default=None, metavar="ID",
                        help="environment ids, or their names without 'auv_envs/' (default: all)")
    parser.add_argument("--agents", nargs="+", default=None, metavar="NAME",
                        help="agent names (default: all registered but the heavy ones)")
    parser.add_argument("--all-agents", action="store_true",
                        help="with no --agents, also run the heavy agents (image front ends, "
                             "about a minute an episode on two cores)")
    parser.add_argument("--obs-modes", nargs="+", default=None, metavar="MODE",
                        help="evaluate each agent in these of its obs modes "
                             "(default: the agent's default mode)")
    parser.add_argument("--episodes", type=int, default=None,
                        help="the full board: this many episodes per pair (every training "
                             f"seed of a group) on the frozen seeds from {EVAL_SEED_BASE} "
                             "(default: the quick board, a group's training seeds in turn, "
                             f"{quick.describe_episodes(DEFAULT_LEVELS)}; "
                             "docs/evaluation.md)")
    parser.add_argument("--design", choices=("quick", "full"), default=None,
                        help="quick: each table its own number of episodes, a group's "
                             "training seeds in turn, the full board's extra agents left out "
                             "(with --seeds: each table takes its first seeds of those); "
                             "full: every agent and training seed on every seed (default: "
                             "quick, full when --episodes or --seeds is given)")
    parser.add_argument("--seeds", type=str, default=None,
                        help="'A-B' or 'A,B,C': override the frozen evaluation seeds")
    parser.add_argument("--env-kwargs", nargs="+", action="append", default=None,
                        metavar="[ENV:]KEY=VALUE",
                        help="environment arguments (Python literals or bare strings); KEY=VALUE "
                             "goes to every env that takes KEY. Repeat the option to evaluate "
                             "several scenarios. Default run: "
                             + ", ".join(f"{e.split('/')[-1]}:{k}={v}"
                                         for e, kw in DEFAULT_ENV_KWARGS.items()
                                         for k, v in kw.items()))
    parser.add_argument("--scenario", type=str, default=None,
                        help="shorthand for adding scenario=NAME to the environment arguments")
    parser.add_argument("--difficulty", nargs="+", default=None,
                        choices=LEVELS, metavar="LEVEL",
                        help=f"difficulty levels to evaluate ({', '.join(LEVELS)}), each a "
                             "scenario of its own (default: "
                             f"{' '.join(DEFAULT_LEVELS) or 'none, the environments defaults'}, "
                             "for each --env-kwargs group that sets no difficulty=; giving "
                             "both is an error)")
    parser.add_argument("--out", type=str, default="results/leaderboard",
                        help="output directory (default results/leaderboard)")
    parser.add_argument("--new-board", action="store_true",
                        help="start a new board in --out instead of merging into the one there "
                             "(by default a run replaces the rows it evaluates and keeps the "
                             "others; the earlier episodes stay cached either way)")
    parser.add_argument("--cache-dir", type=str, default=None,
                        help="episode cache (default OUT/episodes)")
    parser.add_argument("--no-cache", action="store_true",
                        help="run every episode again and refresh the cache (the key already "
                             "covers the task and the code and assets of auv_envs and baselines; "
                             "use this e.g. after upgrading a dependency)")
    parser.add_argument("--backend", choices=BACKENDS, default="local",
                        help="local processes (default) or Ray tasks")
    parser.add_argument("--ray-address", type=str, default=None,
                        help="address of an existing Ray cluster (default: start a local Ray); "
                             "the source tree and the shipped policies go with the job, so each "
                             "node needs only the Python environment, and the rows and clips "
                             "come back to this machine")
    parser.add_argument("--workers", type=int, default=default_workers(),
                        help="local worker processes, 1 = in this process; with a local Ray, "
                             f"its CPUs (default {default_workers()})")
    parser.add_argument("--agent-module", nargs="+", default=[], metavar="MODULE",
                        help="modules to import first (and in every worker) that register agents")
    parser.add_argument("--policy", nargs="+", default=[], metavar="PATH",
                        help="also rank these trained policies: a train.py run directory or an "
                             "exported policy directory each (named <directory>@<weights hash>; "
                             "evaluated on the environment and obs mode they were trained on)")
    parser.add_argument("--record-video", type=str, default=None, metavar="DIR",
                        help="record the first seed's episode of every (environment, agent) as "
                             "MP4 and GIF in DIR; the HTML page shows them (default: MP4 only, "
                             "in OUT/videos)")
    parser.add_argument("--no-video", action="store_true", help="record no clips")
    parser.add_argument("--video-size", type=parse_size, default=(320, 240), metavar="WxH",
                        help="clip frame size, both even (default 320x240)")
    parser.add_argument("--video-speed", type=float, default=None,
                        help="clip playback speed relative to real time (default: a "
                             "full-length episode plays in 20 s)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--verbose", action="store_true",
                        help="print every headline column and the skipped pairs (the files "
                             "always have them)")
    parser.add_argument("--list", action="store_true",
                        help="list the environments and agents (where each applies) and exit")
    return parser


def listing() -> str:
    """The registered environments (obs modes, arguments) and agents (modes, environments)."""
    lines = ["environments:"]
    for env_id in auv_envs.ENVIRONMENTS:
        lines.append(f"  {env_id}  obs modes: {', '.join(env_obs_modes(env_id) or ('?',))}; "
                     f"arguments: {', '.join(env_parameters(env_id))}")
    lines.append("agents:")
    for name in agent_names():
        spec = agent_spec(name)
        where = ", ".join(spec.env_ids) if spec.env_ids is not None else "every environment"
        needs = "".join(f"; needs {k}={v}" for k, v in spec.env_kwargs.items())
        lines.append(f"  {name}  obs modes: {', '.join(spec.obs_modes)}; on {where}{needs}"
                     f" -- {spec.description}")
    groups = sorted(set(agent_groups().values()))
    if groups:
        lines.append("groups (training seeds pooled into one row; the name runs them all):")
        lines += [f"  {group} = {', '.join(group_members(group))}" for group in groups]
    return "\n".join(lines)


def earlier_board(out: str, agent_modules: list[str]) -> tuple[list, list[str]]:
    """The tasks of the board in ``out`` that can be merged into, and the agent modules
    with the board's added. Rows whose environment or agent is gone (a policy directory
    removed, a module not importable) are left out, and said so on stderr.

    Raises:
        BoardError: the board file is unreadable (a usage error: ``--new-board``).
    """
    tasks, modules = board.read(out)
    usable = list(agent_modules)
    for module in modules:
        if module in usable:
            continue
        try:
            import_agent_modules([module])
            usable.append(module)
        except Exception as exc:  # noqa: BLE001 - any failure: its rows cannot be kept
            print(f"note: the board in {out} used {module}, which fails now ({exc}); its "
                  f"rows are dropped", file=sys.stderr)
    known = set(agent_names())
    kept = [t for t in tasks if t.agent in known and t.env_id in auv_envs.ENVIRONMENTS]
    if len(kept) < len(tasks):
        print(f"note: {len(tasks) - len(kept)} episodes of the board in {out} name an agent "
              f"or environment that no longer exists; dropped", file=sys.stderr)
    return kept, usable


def video_available() -> bool:
    """Whether clips can be written (MoviePy, the ``video`` extra); says so when not."""
    try:
        import moviepy  # noqa: F401
    except ImportError:
        print("note: no clips: recording needs the video extra (pip install -e '.[video]'); "
              "the leaderboard is complete without them", file=sys.stderr)
        return False
    return True


def _interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


def main(argv=None, prog: str = "python evaluate.py") -> int:
    """The command line; SIGTERM stops a run like Ctrl-C (finished episodes stay cached).

    ``prog`` is how the user ran it (recorded in the leaderboard's metadata).
    """
    if threading.current_thread() is not threading.main_thread():
        with one_line_errors(prog):
            return _main(argv, prog)
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        with one_line_errors(prog):
            return _main(argv, prog)
    except KeyboardInterrupt:
        print("\ninterrupted: finished episodes are cached; run the same command again to "
              "resume", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)


def console() -> int:
    """The installed ``auv-evaluate`` command."""
    return main(prog="auv-evaluate")


def _main(argv, prog: str) -> int:
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    argv = sys.argv[1:] if argv is None else list(argv)
    if args.backend == "ray":  # before any work
        require("ray", "ray", "--backend ray")
    try:
        if args.workers < 1:
            raise ValueError(f"--workers must be >= 1, got {args.workers}")
        agent_modules = [*args.agent_module,
                         *(POLICY_PREFIX + os.path.abspath(p) for p in args.policy)]
        import_agent_modules(agent_modules)
        agents = args.agents
        if args.policy and agents is not None:  # --agents picks built-ins; --policy adds
            from baselines.rl.agents import external_policy_name

            agents = [*agents, *(external_policy_name(p) for p in args.policy)]
        if args.list:
            print(listing())
            return 0
        env_ids = resolve_env_ids(args.envs or auv_envs.ENVIRONMENTS)
        if agents is not None:  # a group's name stands for its training seeds
            agents = resolve_agent_names(agents)
        check_names(env_ids, agents or ())
        quick_board = (args.design == "quick" if args.design is not None
                       else args.episodes is None and args.seeds is None)
        if quick_board and args.episodes is not None:
            raise ValueError("--episodes sets the full board's episodes; the quick board "
                             "plays each table's own (--design quick takes --seeds)")
        if agents is None and not args.all_agents:
            agents, left_out = default_agents(env_ids, quick_board)
            if left_out:
                print(f"left out of this run (--all-agents adds them): "
                      f"{', '.join(left_out)}", file=sys.stderr)
        if args.seeds:
            seeds = parse_seeds(args.seeds)
        else:
            seeds = default_seeds(quick.max_episodes() if quick_board
                                  else args.episodes if args.episodes is not None else 3)
        if any(s < EVAL_SEED_BASE for s in seeds):
            print(f"warning: seeds below {EVAL_SEED_BASE} may overlap training seeds",
                  file=sys.stderr)
        groups = scenario_groups(args.env_kwargs or [[]], args.scenario, args.difficulty)
        defaults = {e: kw for e, kw in DEFAULT_ENV_KWARGS.items() if e in env_ids}
        variants = [resolve_env_kwargs(env_ids, group, defaults) for group in groups]
        # The page's clips are MP4s; GIFs (slow to write) when DIR is asked for.
        video = None if args.no_video or not video_available() else VideoSpec(
            args.record_video or os.path.join(args.out, "videos"), args.video_size,
            None if args.video_speed is None else check_speed(args.video_speed),
            gif=args.record_video is not None)
        earlier = []
        if not args.new_board:
            earlier, agent_modules = earlier_board(args.out, agent_modules)
        run = evaluate_all(
            env_ids, agents, seeds, args.obs_modes, variants,
            cache_dir=args.cache_dir or os.path.join(args.out, "episodes"),
            refresh=args.no_cache, backend=args.backend, workers=args.workers,
            ray_address=args.ray_address, agent_modules=agent_modules,
            progress=not args.no_progress, video=video, earlier=earlier,
            select=(lambda tasks: quick.thin(tasks, seeds, agent_groups())) if quick_board
            else None,
        )
    except (ValueError, KeyError, RuntimeError) as exc:  # PolicyFileError is a RuntimeError
        parser.error(str(exc.args[0]) if isinstance(exc, KeyError) else str(exc))
    if not run.rows:
        for skip in run.skipped:
            print(f"skipped {skip['agent']} on {skip['env_id']}: {skip['reason']}",
                  file=sys.stderr)
        print("no (env, agent) pair applies; nothing evaluated", file=sys.stderr)
        return 1
    if run.skipped:
        print(f"skipped {len(run.skipped)} (env, agent) pairs that do not apply; reasons in "
              f"{os.path.join(args.out, 'leaderboard.md')}", file=sys.stderr)
    summary = summarise(run.rows, agent_groups())
    summary += bound_rows(summary)
    meta = {
        "command": f"{prog} {shlex.join(argv)}".strip(),
        "seeds": (f"{seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1))
                  else ",".join(map(str, seeds)))
        + (" (the quick board: each table its first seeds of these, a group's training "
           "seeds in turn; docs/evaluation.md)" if quick_board else ""),
        "auv_envs version": auv_envs.__version__,
    }
    clips = {key: Path(os.path.relpath(path, args.out)).as_posix()
             for key, path in run.clips.items()}
    if run.kept:
        meta["merged"] = (f"{run.kept} episodes of earlier runs kept in rows this run did not "
                          f"evaluate (--new-board starts afresh)")
    paths = leaderboard.write(args.out, summary, run.skipped, run.rows, meta, clips=clips)
    board.write(args.out, run.tasks, agent_modules)
    print(leaderboard.markdown(summary, run.skipped if args.verbose else (),
                               compact=not args.verbose))
    stats = run.stats
    rejected = (f" ({stats.rejected} cached episodes rejected and run again: see the "
                f"warnings above)" if stats.rejected else "")
    retried = ""
    if args.backend == "ray":
        retried = f", {stats.retried} retried" + (
            " (Ray ran them again: a worker or node was lost)" if stats.retried else "")
    print(f"{len(run.rows)} episodes: {stats.ran} run, {stats.cached} from the cache{rejected}, "
          f"{stats.failed} failed{retried}; wrote {paths['leaderboard.html']} and "
          f"{len(paths) - 1} more files under {args.out}", file=sys.stderr)
    if video is not None:
        kind = "MP4 and GIF" if video.gif else "MP4"
        print(f"{len(run.clips)} clips ({kind}) in {video.directory}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
