"""Rank every applicable agent on every environment: ``python evaluate.py --help``.

The same command as the installed ``auv-evaluate``; the code is
:mod:`baselines.commands.evaluate`.
"""

import sys

from baselines.commands.evaluate import main

if __name__ == "__main__":
    sys.exit(main())
