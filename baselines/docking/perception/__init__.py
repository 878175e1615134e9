"""Docking perception: [LAMP]'s lamp-array tracker, from camera image to labelled lamp pixels.

``segmentation`` (lamp blobs in a frame), ``identity`` (which blob is which lamp),
``lamp_tracking`` (one EKF per lamp, the tracker's parameters and tracks) and ``front_end``
(their composition as a front end for the features-mode agents).
"""
