"""Docking baselines, cut by role.

``perception`` (seed 002's lamp-array tracker on the camera image), ``estimation`` (seed 003's
EKF and MHE on the light pixels, the lamp tracker's camera-position filter), ``control``
(seed 003's offset-free NMPC in CasADi, the scripted PD reference) and ``agents`` (the thin
agents that wire them from ``env.calibration``, and every docking registration).
"""
