"""Seed 003 docking baselines: offset-free NMPC with EKF or MHE observers (CasADi)."""
