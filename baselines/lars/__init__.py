"""Seed 000 LARS capture baselines.

LTAT perception, cubature Kalman filter, quintic trajectories and PD arm control.
"""
