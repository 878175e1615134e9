"""LARS arm control (seed 000 §2.4, §3.4): quintic trajectory, IK, computed-torque PD."""
