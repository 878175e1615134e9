"""Offline training for the LARS baselines (the Siamese tracker's weights)."""
