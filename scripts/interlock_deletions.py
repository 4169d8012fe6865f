"""Benchmark (docs/round.md, "Certified robustness"): does the independent checker catch every interlock a round
needs? Each interlock of a planned round is deleted in turn and the set checked again.

    python scripts/interlock_deletions.py <stem>_trajectory.csv [...] -- [the stage's overrides: rig=twin ...]

For each planned set (its siblings ``_round.csv``, ``_round.json``, ``_actions.csv``, ``_interlocks.csv``): the
intact set, then one copy per interlock without it, each checked by ``scripts/check_round.py --execute N``
(``N``: ``--execute`` below, default 1000) in a separate process. A row per check: the interlock deleted, the
checker's exit, the certified violating pairs and least certified distance (the exact certification), and the
violating draws of the sampled executions (the second line of evidence). The claim under test: the intact set
exits 0, and every deletion exits 1 (a deleted interlock the round did not need would exit 0 and is listed as
such). One MLflow run (``interlock-deletions``) holds the table.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
SIBLINGS = ("_trajectory.csv", "_round.csv", "_round.json", "_actions.csv")


def check(traj: Path, overrides: list[str], draws: int) -> dict:
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "check_round.py"), str(traj), *overrides,
                           "--execute", str(draws)], capture_output=True, text=True, cwd=ROOT)
    doc = json.loads(done.stdout) if done.returncode in (0, 1) and done.stdout.strip() else {}
    ex = doc.get("execution") or {}
    cert = ex.get("certified") or {}
    return {"exit": done.returncode, "violating_pairs": cert.get("violating_pairs"),
            "least_certified_m": cert.get("least_certified_distance_m"),
            "violating_draws": ex.get("violating_draws"), "draws": ex.get("draws"),
            "error": done.stderr.strip().splitlines()[-1] if done.returncode not in (0, 1) and done.stderr else ""}


def deletions(traj: Path, overrides: list[str], draws: int) -> list[dict]:
    stem = traj.name.removesuffix("_trajectory.csv")
    locks = pd.read_csv(traj.with_name(f"{stem}_interlocks.csv"), keep_default_na=False)
    rows = [{"set": stem, "deleted": "none (intact)", **check(traj, overrides, draws)}]
    print(rows[-1], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for k, lock in locks.iterrows():
            folder = Path(tmp) / str(k)
            folder.mkdir()
            for suffix in SIBLINGS:
                shutil.copy2(traj.with_name(stem + suffix), folder / (stem + suffix))
            locks.drop(index=k).to_csv(folder / f"{stem}_interlocks.csv", index=False)
            name = f"{lock['boom']}#{lock['action']} after {lock['after_boom']}#{lock['after_action']}"
            rows.append({"set": stem, "deleted": name, **check(folder / f"{stem}_trajectory.csv", overrides, draws)})
            print(rows[-1], flush=True)
    return rows


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trajectories", nargs="+", type=Path)
    ap.add_argument("--execute", type=int, default=1000)
    # the stage's overrides follow "--" (argparse would take them for more trajectories)
    cut = argv.index("--") if "--" in argv else len(argv)
    args, overrides = ap.parse_args(argv[:cut]), argv[cut + 1:]
    rows = [r for t in args.trajectories for r in deletions(t.resolve(), overrides, args.execute)]
    table = pd.DataFrame(rows)
    print(table.to_markdown(index=False))
    intact = table["deleted"] == "none (intact)"
    missed = table[~intact & (table["exit"] == 0)]
    print(f"intact sets clean: {int((table[intact]['exit'] == 0).sum())} of {int(intact.sum())}; deletions caught: "
          f"{int((table[~intact]['exit'] == 1).sum())} of {int((~intact).sum())}; passed: {len(missed)}; "
          f"of those caught, missed by every sampled draw: "
          f"{int(((table['exit'] == 1) & ~intact & (table['violating_draws'] == 0)).sum())}")
    sys.path.insert(0, str(ROOT))
    from pipeline.core.config import compose
    from pipeline.tracking.runs import TrackingSettings, stage_run

    with stage_run(TrackingSettings.from_config(compose([o for o in overrides if "=" in o]).tracking),
                   "interlock-deletions", {"stage": "script", "mode": "benchmark"}) as run:
        run.log_params({"sets": [t.name for t in args.trajectories], "draws": args.execute})
        run.log_table(table, "deletions.json")
        run.log_metrics({"deletions": int((~intact).sum()), "deletions_passed": len(missed)})


if __name__ == "__main__":
    main(sys.argv[1:])
