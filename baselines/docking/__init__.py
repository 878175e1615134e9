"""Docking baselines, cut by role.

``perception`` ([LAMP]'s lamp-array tracker on the camera image), ``estimation`` ([OFNMPC]'s
EKF and MHE on the light pixels, the lamp tracker's camera-position filter), ``control``
([OFNMPC]'s offset-free NMPC in CasADi, the scripted PD reference) and ``agents`` (the thin
agents that wire them from ``env.calibration``; :mod:`baselines.catalogue` declares them).
"""
