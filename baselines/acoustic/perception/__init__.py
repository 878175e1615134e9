"""Acoustic perception ([GMPHD] §1): one sub-band's TDOA and DOA measurements -> position fixes.

* :mod:`.positioning`: the fused TDOA-DOA least squares per detection (§1.1-1.3), with
  noise weighting, the model test, node dropouts, and the online clock-offset estimate.
"""
