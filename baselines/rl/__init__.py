"""Reinforcement-learning agents.

Stable-Baselines3 training (train.py) and shipped policies loaded as agents.
"""
