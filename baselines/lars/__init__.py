"""[LTAT] LARS capture baselines, cut by role.

* :mod:`baselines.lars.perception`: Siamese tracker, online detector, LTAT,
  marker corners and the marker pose measurement.
* :mod:`baselines.lars.estimation`: cubature Kalman filter, the AUV motion model
  and the AUV state estimators (marker fixes or the true state).
* :mod:`baselines.lars.control`: quintic trajectories, IK, PD arm control and
  the capture planner (phases, capture goal, re-planning).
* :mod:`baselines.lars.training`: offline training of the Siamese tracker.
* :mod:`baselines.lars.agents`: the agents that wire them (declared in :mod:`baselines.catalogue`).
"""
