"""Docking estimation: the state and disturbance observers of [OFNMPC] (EKF, MHE) and the
rigid-array camera-position filter of the lamp tracker [LAMP]; each module states the
equations it implements.
"""
