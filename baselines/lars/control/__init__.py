"""LARS arm control ([LTAT] §2.4, §3.4): quintic trajectory, IK, computed-torque PD
(:mod:`.arm`) and the capture planner (:mod:`.capture`)."""
