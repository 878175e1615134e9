"""The whole docking approach: ``auv_envs/DockingMission-v0``.

The docking family's transition (:mod:`auv_envs.tasks.docking.transition`) with a
:class:`~auv_envs.tasks.docking.transition.MissionSpec`: the episode starts 100-300 m
from the station, and the lights come out of the water's haze only near it.
"""

from __future__ import annotations

import inspect

from auv_envs.core.env import check_choice
from auv_envs.tasks.docking.config import CLEAR_OCEAN, LAYOUTS  # noqa: F401  (their old home)
from auv_envs.tasks.docking.env import DockingTask
from auv_envs.tasks.docking.navigation import NavigationSensors


class DockingMissionTask(DockingTask):
    """The whole approach to a docking station: acoustic homing from 100-300 m, the
    hand-over to the lights, and the terminal docking.

    **Description.** The vehicle, the plant, the currents, the station (either layout)
    and the success tolerances are those of ``DockingStation-v2`` /
    ``LampArrayDocking-v2``, but the episode starts far away, where only the navigation
    sensors help: the ``nav`` modes' DVL, AHRS, depth and USBL fixes of the station's
    transponder (:mod:`auv_envs.tasks.docking.navigation`). The lights are detectable only from
    the range the water allows (``optics``; Jerlov IA at ``easy``, 1C at ``paper``, 7C at
    ``hard``: about 30, 16 and 8 m). The docking ids' rules change where a long
    approach needs it: the vehicle may start behind the station and go round (passing
    the entrance plane fails only within 3 m of the entrance), losing the lights fails
    nothing, and out of bounds is 500 m from the entrance.

    **Action space.** As the docking ids': ``Box(-1, 1, (4,))``, normalised X, Y, Z, N.

    **Observation space.** As the docking ids' (``state``, ``features``, ``image``,
    ``nav``, ``nav_features``); ``nav_features`` is the one a full docking strategy
    needs.

    **Rewards.** As the docking ids': ``progress`` (the decrease of the distance to the
    entrance plus half the heading error), ``control``, ``visibility`` (-0.01 a step
    with fewer than ``min_visible_lights`` in view), ``success`` (+10), ``failure``
    (-10).

    **Starting state.** The entrance's distance 100-300 m horizontally, at a bearing
    uniform around the station; 3-30 m above the seabed; any heading; surge 0-0.3 m/s;
    the level's current.

    **Episode end.** Terminated on docking (the docking ids' tolerances) or failure
    (``behind_entrance`` within 3 m, ``seabed``, ``out_of_bounds`` beyond 500 m,
    ``surfaced``: the centre of gravity at the surface, ``navigation.station_depth`` =
    50 m above the entrance); truncated after ``time_limit`` s (600).

    **Info.** As the docking ids' every step (errors at the entrance, lights in view,
    violations, ground truth); at the end ``episode_metrics``: the docking ids' terminal
    ones, and per phase:
    ``path_length`` (m), ``homing_time`` (s to the hand-over), ``homing_path_length``,
    ``handover_range`` (the nose's distance from the entrance) and
    ``handover_cross_track`` (its distance from the docking axis) at the hand-over: the
    first step with ``min_visible_lights`` lights in view within the water's detection
    range (a lamp detected half the time; None without a hand-over).

    **Arguments.** Those of the docking ids but ``lights_lost_timeout``, and ``layout``:
    ``"six_lights"`` (the default, [OFNMPC]) or ``"lamp_array"`` ([LAMP]).
    ``time_limit`` defaults to 600 s.

    **Version history.** v0: the first.
    """

    _variant = {"mission": True}  # and the layout given (the station's levels, clear ocean)

    def __init__(self, obs_mode: str = "state", layout: str = "six_lights",
                 time_limit: float = 600.0, navigation: NavigationSensors | None = None,
                 **kwargs):
        if "lights_lost_timeout" in kwargs:
            raise TypeError("DockingMission has no lights-lost failure: the lights are out of "
                            "sight until the hand-over (lights_lost_timeout is the docking "
                            "ids' argument)")
        check_choice("layout", layout, LAYOUTS)
        self._variant = {"mission": True, "layout": layout}
        super().__init__(obs_mode=obs_mode, time_limit=time_limit, navigation=navigation,
                         **kwargs)
        self._init_kwargs["layout"] = layout
        del self._init_kwargs["lights_lost_timeout"]  # the docking ids' default, not ours


def _signature() -> inspect.Signature:
    """The mission's constructor as callers see it: its own arguments, then the docking
    ids' it passes on (``inspect.signature`` reads it: the evaluation's ``KEY=VALUE``
    routing, the documentation)."""
    own = inspect.signature(DockingMissionTask.__init__).parameters
    base = inspect.signature(DockingTask.__init__).parameters
    keep = [p for name, p in own.items() if p.kind != p.VAR_KEYWORD and name != "self"]
    keep += [p for name, p in base.items()
             if name not in own and name not in ("self", "lights_lost_timeout")
             and p.kind != p.VAR_KEYWORD]
    keep += [p for p in base.values() if p.kind == p.VAR_KEYWORD]
    return inspect.Signature(keep)


DockingMissionTask.__signature__ = _signature()
