"""Acoustic tracking of an underwater arm's end effector with an 8-hydrophone
array [GMPHD].

``transition`` the episode (reset and step over a typed state), ``env`` its
task on the CPU (which the one Gymnasium env runs), ``bound`` its posterior Cramér–Rao bound,
``render`` its pictures, ``fluid`` MuJoCo's ellipsoid fluid model in JAX, ``mjx_plant``
the rig on MJX, ``randomization`` the batched worlds' domain randomiser (the measurement
model is ``auv_envs.core.acoustics``, which the docking family's USBL shares; the tracking
metrics are ``auv_envs.metrics``, which the LARS and docking reproductions use too).
"""
