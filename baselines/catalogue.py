"""Every built-in agent, declared once: its name, where it applies, how it is built.

A new agent is its algorithm (a module under its paper family) plus one
entry here. Factories are ``"module:attribute"`` paths, imported only when
the agent is built (:func:`~baselines.registry.lazy`), so listing the agents
imports neither torch nor CasADi. The RL policies shipped in
``assets/policies/`` are registered from their manifests
(:mod:`baselines.rl.agents`); the catalogue names them through
:func:`baselines.rl.agents.shipped_policy_specs`.

Importing this module fills the registry (:mod:`baselines.registry`, which
knows nothing of the catalogue); ``import baselines`` imports it, so every
caller of the registry sees these agents.

Paper keys ([OFNMPC], [LAMP], [LTAT], [GMPHD]) are in the README's
References table.
"""

from __future__ import annotations

from baselines.frontend import front_end_spec
from baselines.registry import AgentSpec, env_ids_of, lazy, register_source

#: Every registered id of each environment family (the module of its entry point).
DOCKING = env_ids_of("auv_envs.tasks.docking.env")
MISSION = env_ids_of("auv_envs.tasks.docking.mission")
LARS = env_ids_of("auv_envs.tasks.lars.env")
ACOUSTIC = env_ids_of("auv_envs.tasks.acoustic.env")

AGENTS: tuple[AgentSpec, ...] = (
    AgentSpec(
        "random", lazy("baselines.agents.random_agent:RandomAgent"), "state", None,
        "uniform random actions",
    ),
    # --- docking [OFNMPC], [LAMP]
    AgentSpec(
        "pd-state", lazy("baselines.docking.agents:DockingPDAgent"), "state", DOCKING,
        "scripted PD on the privileged state (reference controller)",
    ),
    AgentSpec(
        "homing-pd-state", lazy("baselines.docking.agents:HomingPDAgent"), "state", MISSION,
        "privileged reference of the whole approach: line-of-sight homing to the docking "
        "axis, then pd-state's controller, on the true state",
    ),
    AgentSpec(
        "nav-homing-ofnmpc-ekf", lazy("baselines.docking.agents:MissionAgent"),
        "nav_features", MISSION,
        "the whole approach: AHRS/DVL/depth/USBL error-state filter + line-of-sight homing, "
        "handing over to ofnmpc-ekf once the lights are tracked [OFNMPC]",
    ),
    AgentSpec(
        "ofnmpc-ekf", lazy("baselines.docking.agents:OFNMPCAgent", observer="ekf"),
        "features", DOCKING, "offset-free NMPC + EKF on the light pixels [OFNMPC]",
    ),
    AgentSpec(
        "ofnmpc-mhe", lazy("baselines.docking.agents:OFNMPCAgent", observer="mhe"),
        "features", DOCKING, "offset-free NMPC + MHE on the light pixels [OFNMPC]",
    ),
    AgentSpec(
        "ofnmpc-state", lazy("baselines.docking.agents:StateOFNMPCAgent"), "state", DOCKING,
        "privileged reference: offset-free NMPC on the true state (no vision, no observer)",
    ),
    *(
        front_end_spec(
            f"ofnmpc-{observer}-image", inner=f"ofnmpc-{observer}",
            front_end=lazy("baselines.docking.perception.front_end:LampArrayFrontEnd.from_env"),
            obs_mode="image", env_ids=DOCKING,
            description=f"[LAMP] lamp-array tracker on the camera image -> "
                        f"OFNMPC-{observer.upper()} [OFNMPC]",
            heavy=True,  # a 640x480 frame through the front end every step: ~1 min an episode
        )
        for observer in ("ekf", "mhe")
    ),
    # --- LARS capture [LTAT]
    AgentSpec(
        "ckf-pd", lazy("baselines.lars.agents:CKFPDAgent"), "features", LARS,
        "[LTAT] estimation+control: stereo marker fixes -> CKF -> quintic + IK + PD (torques)",
    ),
    AgentSpec(
        "ckf-pd-state", lazy("baselines.lars.agents:TrueStateCKFPDAgent"), "state", LARS,
        "privileged reference: ckf-pd's capture strategy + quintic + IK + PD on the true "
        "AUV state",
    ),
    front_end_spec(
        "ltat-ckf-pd", inner="ckf-pd",
        front_end=lazy("baselines.lars.agents:make_front_end"), obs_mode="stereo",
        env_ids=LARS,
        description="[LTAT]: LTAT (Siamese tracker + online detector) -> marker corners -> "
                    "CKF + PD",
    ),
    # --- acoustic tracking [GMPHD]
    AgentSpec(
        "gmphd-gci", lazy("baselines.acoustic.agents:GMPHDGCIAgent"), "measurements",
        ACOUSTIC, "[GMPHD]: fused TDOA-DOA LS, per-band GM-PHD, GCI fusion",
    ),
    AgentSpec(
        "gmphd-single", lazy("baselines.acoustic.agents:single_band_agent"), "measurements",
        ACOUSTIC, "GM-PHD with DBSCAN birth on the single best band",
    ),
    AgentSpec(
        "ls-kf", lazy("baselines.acoustic.agents:LSKalmanAgent"), "measurements", ACOUSTIC,
        "fused LS fixes + Kalman filter with nearest-neighbour gating",
    ),
)


def builtin_specs() -> tuple[AgentSpec, ...]:
    """The catalogue's agents and the shipped RL policies (read from their manifests)."""
    from baselines.rl.agents import shipped_policy_specs  # reads assets/policies/

    return (*AGENTS, *shipped_policy_specs())


# Registered at the first lookup, not now: the manifests are read only when asked for.
register_source(builtin_specs)
