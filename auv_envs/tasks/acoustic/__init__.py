"""Acoustic tracking of an underwater arm's end effector with an 8-hydrophone
array [GMPHD].

``transition`` the episode (reset and step over a typed state), ``env`` its
Gymnasium shell, ``bound`` its posterior Cramér–Rao bound,
``render`` its pictures (the measurement model is ``auv_envs.core.acoustics``,
which the docking mission's USBL shares).
"""
