"""Seed 004's acoustic tracking pipeline: LS positioning, GM-PHD per band, GCI fusion.

Components (one role each, wired through constructors):
:mod:`~baselines.acoustic.positioning` (fused TDOA-DOA least squares),
:mod:`~baselines.acoustic.gmphd` (constant-velocity GM-PHD filter bank with
DBSCAN adaptive birth), :mod:`~baselines.acoustic.gci` (generalized
covariance intersection of Gaussian mixtures),
:mod:`~baselines.acoustic.agents` (the ``gmphd-gci``, ``gmphd-single`` and
``ls-kf`` agents).
"""
