"""Agents that act in ``auv_envs`` environments: classical baselines and scripted references."""

# The catalogue fills the agent registry; importing it here means that any
# import of ``baselines.registry`` (the commands, the scripts, the
# ``auv_envs.agents`` entry point) sees the built-in agents.
from baselines import catalogue as _catalogue  # noqa: F401
