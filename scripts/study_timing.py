"""Run the study with ``dvc repro`` and time each stage (docs/benchmarks.md, "The study, stage by stage").

    python scripts/study_timing.py --out logs/study_timing.json            # the whole study
    python scripts/study_timing.py --out logs/t.json -- -f -s solver_benchmark    # arguments after -- go to dvc repro

DVC prints ``Running stage '<name>':`` as each stage starts; a stage's time is from that line to
the next one (or to the end), so it includes DVC's own hashing and caching of the stage's outputs.
A stage DVC skips (unchanged) prints no such line and gets no row. Writes the rows as JSON and
prints a Markdown table; exits with ``dvc repro``'s status.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

STAGE_LINE = re.compile(r"Running stage '([^']+)'")


def stage_times(lines, clock=time.monotonic) -> tuple[list[dict], float]:
    """Per stage ``{"stage", "seconds"}`` from DVC's output ``lines`` as they arrive (echoed), and
    the total seconds."""
    t0 = clock()
    starts: list[tuple[str, float]] = []
    for line in lines:
        sys.stdout.write(line)
        found = STAGE_LINE.search(line)
        if found:
            starts.append((found.group(1), clock()))
    end = clock()
    rows = [{"stage": name, "seconds": round((starts[i + 1][1] if i + 1 < len(starts) else end) - t, 1)}
            for i, (name, t) in enumerate(starts)]
    return rows, round(end - t0, 1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="JSON file for the rows (not overwritten)")
    parser.add_argument("repro_args", nargs="*", help="arguments for dvc repro (after --)")
    args = parser.parse_args(argv)
    if args.out.exists():
        parser.error(f"--out {args.out} exists; name a new file (an earlier timing is never overwritten)")
    proc = subprocess.Popen(["dvc", "repro", *args.repro_args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, bufsize=1)
    rows, total = stage_times(proc.stdout)
    rc = proc.wait()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"returncode": rc, "total_s": total, "stages": rows}, indent=1) + "\n")
    print("\n| stage | minutes |\n|---|---|")
    for row in rows:
        print(f"| {row['stage']} | {row['seconds'] / 60:.1f} |")
    print(f"| **total** (`dvc repro`, exit {rc}) | **{total / 60:.1f}** |")
    return rc


if __name__ == "__main__":
    sys.exit(main())
