"""LARS capture by a ship's 3-DOF arm with a stereo camera [LTAT].

``env`` the Gymnasium environment; ``arm``, ``physics``, ``scene``, ``calibration``;
the sea (``sea``, ``waves``), sun glint (``glint``) and the stereo rig (``stereo``).
"""
