"""Check a round's trajectory file independently of the planner: dense, from the file alone.

    python scripts/check_round.py data/plans/demo_face_trajectory.csv --rig twin [--dt 0.005]

The file is interpolated linearly every ``dt`` seconds (the file's own rule, spec section 7); frames
come from each boom's own forward kinematics plus its base read from ``conf/rig/<rig>.yaml`` (not
the rig's mounting code); boom-boom distances from :class:`BoomPair` directly, self and tunnel
clearances from each boom's :class:`SafetyModel`; joint speeds from the rows against the motion file.
Prints one JSON object (the smallest boom-boom distance, each boom's smallest self and tunnel
clearance, the largest joint speed over its limit, the violations) and exits 1 when any of them
breaks: boom-boom < d_boom, self or tunnel < 0, a joint faster than its speed; 2 on a missing file or a bad --dt.
"""

from __future__ import annotations

import argparse
import json
import sys
from itertools import combinations
from pathlib import Path

import numpy as np
import pandas as pd
import torch

D = torch.float64
CHUNK = 20000


def _interp(traj: pd.DataFrame, boom: str, names, t: np.ndarray) -> np.ndarray:
    rows = traj[traj["boom"] == boom]
    return np.stack([np.interp(t, rows["t"], rows[n]) for n in names], -1)


def check(trajectory: Path, rig_name: str, dt: float = 0.005, tunnel: str | None = None) -> dict:
    from pipeline.assembly.build import build_safety, load_boom
    from pipeline.core.config import load_group_file
    from pipeline.geometry.boom_pair import BoomPair
    from pipeline.motion.timing import load_motion
    from pipeline.round.benchmark import rig_tunnel

    node = load_group_file("rig", rig_name)
    tunnel_cfg = load_group_file("tunnel", tunnel) if tunnel else rig_tunnel(rig_name, load_group_file(
        "tunnel", "horseshoe"))
    traj = pd.read_csv(trajectory, keep_default_na=False)
    t = np.arange(0.0, float(traj["t"].max()) + dt, dt)
    out = {"samples": len(t), "dt_s": dt, "booms": {}, "violations": []}
    booms, safeties, bases = {}, {}, {}
    for b in node["booms"]:
        booms[b["name"]] = load_boom(b["boom"])
        safeties[b["name"]] = build_safety(booms[b["name"]], tunnel_cfg, load_group_file("safety", "paper"))
        bases[b["name"]] = torch.tensor(b["base"], dtype=D)
    own = {name: {} for name in booms}
    least = np.inf
    with torch.inference_mode():
        for s in range(0, len(t), CHUNK):  # chunks of instants: memory stays bounded on long rounds
            ts = t[s:s + CHUNK]
            frames = {}
            for name, boom in booms.items():
                f = boom.frames(torch.as_tensor(_interp(traj, name, boom.joint_names, ts)))
                f[..., :3, 3] += bases[name]  # the base offset, from the rig file; the tunnel is in the rig frame
                frames[name] = f
                for k, v in safeties[name].clearances_from_frames(f).items():
                    own[name][k] = min(own[name].get(k, np.inf), float(v.min()))
            for a, b in combinations(frames, 2):
                pair = BoomPair(booms[a], booms[b], float(node["d_boom"]))
                least = min(least, float(pair.distances(frames[a], frames[b]).amin()))
    for name, boom in booms.items():
        c = own[name]
        rows = traj[traj["boom"] == name]
        step = np.abs(np.diff(rows[list(boom.joint_names)].to_numpy(), axis=0))
        speed = step / np.diff(rows["t"].to_numpy())[:, None]
        over = float((speed / np.array(load_motion(boom).joints.v)).max())
        out["booms"][name] = {"self_m": c["self"], "tunnel_m": min(c[k] for k in c if k != "self"),
                              "speed_over_limit": over}
        if min(c.values()) < 0:
            out["violations"].append(f"boom {name}: clearance {c}")
        if over > 1 + 1e-9:
            out["violations"].append(f"boom {name}: a joint at {over:.4f} x its speed")
    out["min_boom_distance_m"] = least
    if least < float(node["d_boom"]):
        out["violations"].append(f"boom-boom distance {least:.4f} m < d_boom {node['d_boom']}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("trajectory", type=Path)
    ap.add_argument("--rig", default="twin")
    ap.add_argument("--dt", type=float, default=0.005)
    args = ap.parse_args(argv)
    if not args.trajectory.is_file():
        print(f"check_round: {args.trajectory}: no such trajectory file", file=sys.stderr)
        return 2
    if args.dt <= 0:
        print(f"check_round: --dt {args.dt}: must be > 0", file=sys.stderr)
        return 2
    out = check(args.trajectory, args.rig, args.dt)
    print(json.dumps(out, indent=1))
    return 1 if out["violations"] else 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
