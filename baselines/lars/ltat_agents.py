"""Agent ``ltat-ckf-pd`` (seed 000): LTAT perception in front of the ``ckf-pd`` agent.

The front end (:class:`baselines.lars.ltat.LTATFrontEnd`) turns the
``stereo`` observation of ``auv_envs/LARSCapture-v0`` into its ``features``
observation (marker corners in both views); the inner agent ``ckf-pd``
(stereo triangulation, CKF, quintic trajectory, IK and PD control) acts on
that. The inner agent is looked up when the agent is built: until ``ckf-pd``
is registered, building ``ltat-ckf-pd`` raises ``KeyError``.
"""

from __future__ import annotations

from baselines.frontend import register_front_end_agent

ENV_IDS = ("auv_envs/LARSCapture-v0",)


def make_front_end(env):
    """LTAT front end from the env's documented calibration (weights: the shipped ones)."""
    if getattr(env, "obs_mode", None) != "stereo":
        raise ValueError(f"ltat-ckf-pd needs obs_mode='stereo', got "
                         f"{getattr(env, 'obs_mode', None)!r}")
    # Imported here: torch and the weights load only when the agent is built.
    from baselines.lars.ltat import LTATFrontEnd

    return LTATFrontEnd(env.calibration)


register_front_end_agent(
    "ltat-ckf-pd",
    inner="ckf-pd",
    front_end_factory=make_front_end,
    obs_mode="stereo",
    env_ids=ENV_IDS,
    description="seed 000: LTAT (Siamese tracker + online detector) -> marker corners -> CKF + PD",
)
