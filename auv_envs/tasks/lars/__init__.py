"""LARS capture by a ship's 3-DOF arm with a stereo camera [LTAT].

``transition`` the episode (reset and step over a typed state), ``env`` its
task on the CPU (which the one Gymnasium env runs); ``arm``, ``physics``, ``scene``,
``calibration``; the sea (``sea``, ``waves``), sun glint (``glint``) and the stereo rig
(``stereo``); ``compiled`` the CPU truth compiled, ``mjx_plant`` the arm on MJX (JAX),
``randomization`` the batched worlds' domain randomiser.
"""
