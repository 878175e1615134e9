"""[GMPHD]'s acoustic tracking pipeline: LS positioning, GM-PHD per band, GCI fusion.

Components by role (one role each, wired through constructors):

* :mod:`~baselines.acoustic.perception.positioning`: measurements -> position
  fixes (fused TDOA-DOA least squares, clock-offset estimate);
* :mod:`~baselines.acoustic.estimation.gmphd`: position fixes -> one
  constant-velocity GM-PHD filter per sub-band with DBSCAN adaptive birth;
* :mod:`~baselines.acoustic.estimation.gci`: the band mixtures -> their
  generalized covariance intersection and labelled extraction;
* :mod:`~baselines.acoustic.agents`: the ``gmphd-gci``, ``gmphd-single`` and
  ``ls-kf`` agents wiring the parts above.
"""
