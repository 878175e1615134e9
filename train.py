"""Train a Stable-Baselines3 agent on an ``auv_envs`` environment: ``python train.py --help``.

The same command as the installed ``auv-train``; the code is
:mod:`baselines.commands.train`.
"""

import sys

from baselines.commands.train import main

if __name__ == "__main__":
    sys.exit(main())
