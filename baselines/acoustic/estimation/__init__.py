"""Acoustic estimation ([GMPHD] §2): position fixes of Q sub-bands -> labelled target states.

* :mod:`.gmphd`: one GM-PHD filter per sub-band (prediction, DBSCAN adaptive birth,
  update, pruning and merging, §2.1-2.2).
* :mod:`.gci`: generalized covariance intersection of the Q mixtures and the labelled
  extraction (§2.3).
"""
