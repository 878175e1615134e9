"""Vision front ends.

Seed 002's lamp-array tracker: adaptive thresholding, blobs, per-lamp EKFs, Hungarian
assignment.
"""
