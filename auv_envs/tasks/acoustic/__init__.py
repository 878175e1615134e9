"""Acoustic tracking of an underwater arm's end effector with an 8-hydrophone
array [GMPHD].

``env`` the Gymnasium environment, ``bound`` its posterior Cramér–Rao bound,
``render`` its pictures (the measurement model is ``auv_envs.core.acoustics``,
which the docking mission's USBL shares).
"""
