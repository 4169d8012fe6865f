"""The move benchmark and the redundancy measurement (pipeline/rig_benchmarks/moves.py) on a few demo-face holes:
shares and times consistent with the per-move rows, clear moves with non-negative clearances, the same seed
giving the same sample, move sums against a hand loop over the time model, a one-boom rig refused."""

import math

import pytest
import torch

from pipeline import demo_face, move_benchmark
from pipeline.assembly.rig import build_rig
from pipeline.core.errors import ConfigError
from pipeline.motion.moves import KINDS
from pipeline.motion.timing import move_time, rig_motions
from pipeline.plans.csv_plan import read_csv_plan, write_csv_plan
from pipeline.plans.reach import reach_table, rig_solvers
from pipeline.plans.read import read_plan
from pipeline.rig_benchmarks.moves import MoveBenchmarkSettings, distance_rate, path_time, redundancy
from pipeline.rig_benchmarks.moves import move_benchmark as run_moves
from pipeline.solvers.hybrid import HybridSettings

D = torch.float64


@pytest.fixture(scope="module")
def setup(tmp_path_factory, make_cfg):
    tmp = tmp_path_factory.mktemp("moves")
    cfg = make_cfg(tmp, "rig=twin")
    demo_face.run(cfg)
    holes = read_csv_plan(tmp / "data" / "plans" / "demo_face.csv").holes
    write_csv_plan(holes.iloc[::5].reset_index(drop=True), tmp / "small.csv")  # 13 holes of every type
    plan = read_plan(tmp / "small.csv")
    rig = build_rig(cfg.rig, cfg.tunnel, cfg.safety)
    solvers = rig_solvers(rig, lambda b: None, HybridSettings(deep_starts=32))
    reach = reach_table(plan, rig, solvers, "hybrid (no network)")
    limits = [m.joints for m in rig_motions(cfg.motion, rig.booms)]
    return tmp, rig, plan, solvers, reach, limits


def test_path_time_is_the_sum_of_the_move_times(setup):
    _, rig, _, _, reach, limits = setup
    q = torch.tensor(reach.table[rig.booms[0].boom.joint_names].to_numpy()[:5], dtype=D)
    by_hand = sum(float(move_time(q[k], q[k + 1], limits[0])) for k in range(4))
    assert path_time(q, limits[0]) == pytest.approx(by_hand, rel=1e-12)


def test_redundancy_compares_chained_and_independent_sums(setup):
    _, rig, plan, solvers, reach, limits = setup
    table = redundancy(rig, plan, reach, solvers, limits)
    assert table["boom"].tolist() == rig.names
    for _, row in table.iterrows():
        ok = reach.table[(reach.table["boom"] == row["boom"]) & (reach.table["status"] == "ok")]
        assert row["holes"] == len(ok)
        m = rig.booms[rig.index(row["boom"])]
        q = torch.cat([m.park[None], torch.tensor(ok[m.boom.joint_names].to_numpy(), dtype=D)])
        assert row["independent_move_s"] == pytest.approx(path_time(q, limits[0]), rel=1e-12)
        assert row["chained_move_s"] > 0 and row["nearest_move_s"] > 0
        assert row["chained_saved_pct"] == pytest.approx(
            100 * (row["independent_move_s"] - row["chained_move_s"]) / row["independent_move_s"])


def test_move_benchmark_rows_and_summary_agree(setup):
    _, rig, plan, solvers, reach, limits = setup
    st = MoveBenchmarkSettings(pairs=6, planner_iterations=5000, simplify_steps=20, seed=1)
    table, summary = run_moves(rig, plan, reach, solvers, limits, st)
    assert len(table) == 2 * st.pairs and summary["all.pairs"] == len(table)
    assert set(table["kind"]) <= {*KINDS, "failed", "blocked"}
    tried = table[table["kind"] != "blocked"]
    shares = sum(summary[f"all.{k}_share"] for k in (*KINDS, "failed"))
    assert math.isclose(shares, 1.0) if len(tried) else math.isnan(shares)
    clear = tried[tried["kind"] != "failed"]
    for col in [c for c in clear.columns if c.startswith("min_") and c.endswith("_m")]:
        assert (clear[col] >= 0).all(), col
    if len(clear):
        assert summary["all.move_s_median"] == pytest.approx(float(clear["duration_s"].median()))
    # the same seed, the same pairs and stands
    again, _ = run_moves(rig, plan, reach, solvers, limits, st)
    cols = ["boom", "from", "to", "stand_L", "stand_R"]
    assert again[cols].equals(table[cols])


def test_distance_rate_counts_batched_pairs(setup):
    _, rig, *_ = setup
    rate = distance_rate(rig, MoveBenchmarkSettings(distance_batch=256, distance_repeats=2))
    assert rate["boom_pairs_per_s"] > 0 and rate["boom_pairs_per_s_with_fk"] > 0 and rate["distance_batch"] == 256


def test_the_stage_refuses_a_one_boom_rig(tmp_path, make_cfg):
    with pytest.raises(ConfigError, match=r"rig = 'single' \(conf/rig/single.yaml\) has one boom"):
        move_benchmark.run(make_cfg(tmp_path, "rig=single"))
