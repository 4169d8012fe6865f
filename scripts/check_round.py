"""Check a round's files independently of the planner (docs/round.md, "The independent checker").

    python scripts/check_round.py data/plans/demo_face_trajectory.csv rig=twin [motion.joint_speeds.q1=7.5 ...]
        [--round F] [--summary F] [--plan F] [--spacing-m 0.005] [--collar-tol-mm 0.1] [--angle-tol-deg A]
        [--actions F] [--interlocks F] [--zones F] [--execute N] [--seed S] [--draws F]
    python scripts/check_round.py data/plans/demo_face_executed_trajectory.csv rig=twin --realised

Reads ``<stem>_trajectory.csv`` with its siblings ``<stem>_round.csv`` and ``<stem>_round.json`` and the
plan the JSON names, and ``<stem>_actions.csv`` / ``<stem>_interlocks.csv`` when there (the executed
round, docs/reference.md section 8: its robustness certified exactly for any drilling durations, and the draws;
``--execute N`` adds N random draws and the fixed ones, ``--draws F`` a draws file's; ``<stem>_zones.csv``
or ``--zones F``, zones the booms enter one at a time); ``--realised`` checks an executed round's set
(``<stem>_executed_*``); the settings are composed from ``conf/`` with the stage's own overrides
(``tunnel=profile tunnel.file=<csv>``: a tunnel of any cross-section; ``navigation.pose=[...]`` or
``navigation.points=<csv>``: the plan in its own frame, taken into the rig frame before its holes are
matched). Imports nothing of ``pipeline``: the code is :mod:`round_check` beside this file. Prints one JSON
object; exit 0 clean, 1 violations (or a clearance that cannot be certified), 2 input errors (a file, an
argument out of its range, a setting, a rig or tunnel other than the round's: named on stderr), 3 a failure
of the checker's own (its traceback on stderr, no verdict).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # round_check/, beside this file

from round_check import (  # noqa: E402
    actions,
    boom,
    certify,
    distance,
    episodes,
    execute,
    executed,
    files,
    navigation,
    profile,
    realised,
    settings,
    sweep,
)
from round_check.cli import check, main  # noqa: E402
from round_check.errors import InputError  # noqa: E402

__all__ = ["InputError", "actions", "boom", "certify", "check", "distance", "episodes", "execute", "executed", "files",
           "main", "navigation", "profile", "realised", "settings", "sweep"]

if __name__ == "__main__":
    sys.exit(main())
