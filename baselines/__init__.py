"""Agents that act in ``auv_envs`` environments: classical baselines and scripted references."""
