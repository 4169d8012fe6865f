"""The worked example of docs/plans_to_rig.md: a plan drawn in tunnel coordinates, three measured points,
a D-shaped drift.

    python scripts/plan_frame_example.py [folder]       # default: data/example

Writes, under ``folder``:

- ``d_face_tunnel.csv``: the face designed for the D-shaped drift (``conf/tunnel/profiles/d_5x5.csv``) by the
  demo face's designer, drawn in the tunnel's own frame: chainage along the tunnel (the rig stands at
  chainage 1 250 m, 1.5 m right of the tunnel's centre line, its floor 3.2 m below the tunnel datum, turned
  2.0 deg to the left, its carrier 0.8 deg nose-up);
- ``prisms.csv``: three reference prisms on the walls and the roof, their tunnel coordinates as surveyed and
  their positions as the rig measures them, with 1 mm of measuring noise (seeded);
- ``pose.txt``: the true pose, to compare with the fitted one.

The designer and the numbers are seeded: the same command writes the same files.
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd

from pipeline.assembly.build import build_safety
from pipeline.core.config import compose, project_path
from pipeline.plans.csv_plan import write_csv_plan
from pipeline.plans.demo_face import demo_face
from pipeline.plans.model import COORDS
from pipeline.plans.navigation import pose_from_angles

PROFILE = "conf/tunnel/profiles/d_5x5.csv"
POSE = [1250.0, 1.5, -3.2, 2.0, -0.8, 0.0]  # x (chainage), y, z (m); yaw, pitch, roll (deg)
PRISMS_RIG = np.array([[-10.0, 2.4, 1.5], [5.0, -2.4, 3.0], [-2.0, 0.5, 4.8]])  # left wall, right wall, roof


def main(argv: list[str]) -> None:
    folder = project_path(argv[0] if argv else "data/example")
    folder.mkdir(parents=True, exist_ok=True)
    cfg = compose(["tunnel=profile", f"tunnel.file={PROFILE}"])
    plan = demo_face(safety=build_safety(cfg.boom, cfg.tunnel, cfg.safety))
    pose = pose_from_angles(POSE)
    holes = plan.holes.copy()
    holes[COORDS] = np.round(pose.to_plan(holes[COORDS].to_numpy()), 4)  # a plan's 0.1 mm digits
    write_csv_plan(holes, folder / "d_face_tunnel.csv")
    measured = PRISMS_RIG + np.random.default_rng(2026).normal(0, 0.001, PRISMS_RIG.shape)
    surveyed = pose.to_plan(PRISMS_RIG)
    pd.DataFrame({"point": ["left wall", "right wall", "roof"],
                  **{f"plan_{a}": surveyed[:, i].round(4) for i, a in enumerate("xyz")},
                  **{f"rig_{a}": measured[:, i].round(4) for i, a in enumerate("xyz")}}).to_csv(
        folder / "prisms.csv", index=False)
    (folder / "pose.txt").write_text(f"true navigation.pose = {POSE}\n")
    print(f"wrote {len(holes)} holes to {folder / 'd_face_tunnel.csv'}, three prisms to {folder / 'prisms.csv'}")


if __name__ == "__main__":
    main(sys.argv[1:])
