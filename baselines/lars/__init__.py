"""[LTAT] LARS capture baselines, cut by role.

* :mod:`baselines.lars.perception`: Siamese tracker, online detector, LTAT,
  marker corners and the marker pose measurement.
* :mod:`baselines.lars.estimation`: cubature Kalman filter and the AUV motion model.
* :mod:`baselines.lars.control`: quintic trajectories, IK and PD arm control.
* :mod:`baselines.lars.training`: offline training of the Siamese tracker.
* :mod:`baselines.lars.agents`: the agents that wire them (declared in :mod:`baselines.catalogue`).
"""
