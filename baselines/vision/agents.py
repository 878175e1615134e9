"""Image-mode docking agents: seed 002's lamp-array front end before seed 003's OFNMPC.

``ofnmpc-ekf-image`` and ``ofnmpc-mhe-image`` run :class:`LampArrayFrontEnd` on each ``image``
observation and hand the resulting ``features`` observation (labelled light pixels, visibility,
velocity, attitude) to the ``ofnmpc-ekf`` / ``ofnmpc-mhe`` agents of
:mod:`baselines.docking.agents`. The inner agent is looked up when the agent is built, so
building one before the inner agents are registered raises ``KeyError``. Both are ``heavy``:
a failed 100 s episode is 1000 frames at 640x480 through the front end, 70-120 s on a
shared 2-core machine, so the default leaderboard run leaves them out.
"""

from __future__ import annotations

from baselines.agents.pd_docking import DOCKING_ENV_IDS
from baselines.frontend import register_front_end_agent
from baselines.vision.lamp_array import LampArrayFrontEnd

for _observer in ("ekf", "mhe"):
    register_front_end_agent(
        name=f"ofnmpc-{_observer}-image",
        inner=f"ofnmpc-{_observer}",
        front_end_factory=LampArrayFrontEnd.from_env,
        obs_mode="image",
        env_ids=DOCKING_ENV_IDS,
        description=f"seed 002 lamp-array tracker on the camera image -> OFNMPC-{_observer.upper()}"
        " (seed 003)",
        heavy=True,  # a 640x480 frame through the front end every step: ~1 min an episode
    )
