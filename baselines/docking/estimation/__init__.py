"""Docking estimation: the state and disturbance observers of seed 003 (EKF, MHE) and the
rigid-array camera-position filter of the lamp tracker (seed 002); each module states the
equations it implements.
"""
