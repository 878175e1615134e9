"""Labelled data sets rendered from seeded episodes (for trackers and detectors)."""
