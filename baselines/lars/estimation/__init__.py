"""LARS estimation ([LTAT] §2.3): the cubature Kalman filter and the AUV motion model."""
