"""``python -m round_check`` (installed from the wheel; ``boom-ik-check-round`` is the same command): the
checker of ``scripts/check_round.py``."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
