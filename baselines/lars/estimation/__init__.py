"""LARS estimation ([LTAT] §2.3): the cubature Kalman filter, the AUV motion model
(:mod:`.ckf`) and the AUV state estimators built on them (:mod:`.auv_state`)."""
