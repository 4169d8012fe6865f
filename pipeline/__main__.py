"""``boom-ik <stage> [override ...]`` (or ``python -m pipeline <stage> ...``): every stage in one command.

``boom-ik solve plan=face.csv`` runs exactly ``python -m pipeline.solve plan=face.csv``, in this process: the
stage's ``main`` with the overrides as its command line (Hydra reads them; ``boom-ik solve --help`` is Hydra's
help), its exit code unchanged. ``boom-ik --help`` lists the stages, one line each; no stage name prints that
list and exits 2, an unknown one exits 2 naming the closest. The stages are the modules of ``pipeline/`` whose
``main`` is a ``stage_main`` (:func:`pipeline.core.stage.stage_modules`), found without importing them.
"""

from __future__ import annotations

import difflib
import importlib
import sys

from pipeline.core.exit_codes import ExitCode
from pipeline.core.stage import stage_modules

USAGE = "usage: boom-ik <stage> [override ...]   (boom-ik <stage> --help: the stage's settings)"


def _listing(stages: dict[str, str]) -> str:
    width = max(map(len, stages))
    rows = [f"  {name.ljust(width)}  {line}" for name, line in stages.items()]
    return "\n".join([USAGE, "", "stages (python -m pipeline.<stage>, docs/usage.md):", *rows])


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    stages = stage_modules()
    if not argv or argv[0] in ("-h", "--help"):
        print(_listing(stages), file=sys.stdout if argv else sys.stderr)
        return int(ExitCode.DONE if argv else ExitCode.BAD_INPUT)
    stage, overrides = argv[0], argv[1:]
    if stage not in stages:
        close = difflib.get_close_matches(stage, list(stages), n=1, cutoff=0.4)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        print(f"error: unknown stage {stage!r}{hint} (boom-ik --help lists the stages)", file=sys.stderr)
        return int(ExitCode.BAD_INPUT)
    module = importlib.import_module(f"pipeline.{stage}")
    sys.argv = [module.__file__, *overrides]  # what `python -m pipeline.<stage>` gives Hydra
    module.main()
    return int(ExitCode.DONE)


if __name__ == "__main__":
    sys.exit(main())
