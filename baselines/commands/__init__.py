"""The command lines: ``auv-evaluate`` (leaderboard) and ``auv-train`` (SB3 training).

The checkout's ``evaluate.py`` and ``train.py`` run the same functions.
"""
