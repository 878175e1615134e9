"""LARS perception ([LTAT] §2.1-2.2): stereo images -> marker corners -> AUV pose fixes.

* :mod:`.siamese`: the Siamese tracker at inference (network, crops, weights).
* :mod:`.corners`: the marker's three corners in one image.
* :mod:`.stereo`: corners of the two views matched and checked; the marker found without prior.
* :mod:`.detector`: the online-learned detector.
* :mod:`.ltat`: long-term anti-interference tracking, the composition of the above.
* :mod:`.front_end`: LTAT as a front end (``stereo`` -> ``features`` observation).
* :mod:`.marker`: the marker pose measurement (triangulation, eqs. 2-6).
"""
