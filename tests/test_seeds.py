"""Training faster and with error bars: the hidden layers in bfloat16 while training (input and output layers in
float32), and the spread over seeds the evaluation and the report give."""

import numpy as np
import pandas as pd
import pytest
import torch

from pipeline.evaluation.seeds import seed_checkpoints, seed_spread, seed_table
from pipeline.learning.models import build_model
from pipeline.learning.training import Objective, dataset_batches, fit, training_dtype
from pipeline.report import render


def test_the_precision_setting_resolves_on_each_device():
    assert training_dtype("float32", "cpu") is None
    assert training_dtype("bfloat16", "cpu") is torch.bfloat16
    native = torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()
    assert training_dtype("auto", "cpu") is (torch.bfloat16 if native else None)


def _net(safety, width=64, depth=3):
    torch.manual_seed(0)
    pose = safety.boom.pose6(torch.rand(256, safety.boom.n_joints, dtype=torch.float64)
                             * (safety.boom.limits()[1] - safety.boom.limits()[0]) + safety.boom.limits()[0]).float()
    return build_model(safety.boom, pose.mean(0), pose.std(0), width, depth, "gelu"), pose


def test_bfloat16_hidden_layers_keep_float32_at_the_ends(safety):
    """The hidden products are bfloat16 (the answer differs from float32's, by about bfloat16's resolution), the
    output float32; an independent reference (the hidden layers' inputs and weights rounded to bfloat16 by hand,
    products summed in float64) agrees with it far closer than float32's answer does."""
    net, pose = _net(safety)
    with torch.no_grad():
        full = net.unit_joints(pose)
        half = net.unit_joints(pose, torch.bfloat16)
        assert half.dtype == torch.float32 and not torch.equal(full, half)
        assert (half - full).abs().max() < 2e-2
        x = (pose - net.in_mean) / net.in_std
        h = net.net[:2](x).double()  # the input layer, float32
        for layer, act in zip(net.net[2:-1:2], net.net[3:-1:2], strict=True):
            w, b = (t.to(torch.bfloat16).double() for t in (layer.weight, layer.bias))
            z = (h.to(torch.bfloat16).double() @ w.T + b).to(torch.bfloat16)  # autocast's output dtype
            h = act(z.float()).to(torch.bfloat16).double()
        ref = torch.sigmoid(net.net[-1].double()(h))
    assert (half.double() - ref).abs().max() < 0.1 * (full.double() - ref).abs().max()


def test_a_training_in_bfloat16_learns_as_float32_does(safety):
    """The same short training in both precisions: every weight receives updates, the losses stay finite and fall,
    and the held-out errors end within 20 % of each other (measured at full length in docs/benchmarks.md)."""
    ends = {}
    for dtype in (None, torch.bfloat16):
        net, pose = _net(safety, 64, 3)
        before = {k: v.clone() for k, v in net.state_dict().items()}
        history = fit(net, safety.boom, safety, Objective(False, 1.0, 0.0, "norm"),
                      dataset_batches(pose, None, 64, 1), 150, 3e-3, pose[:64], eval_every=50, progress=False,
                      hidden_dtype=dtype)
        changed = [k for k, v in net.state_dict().items() if k.startswith("net.") and not torch.equal(v, before[k])]
        assert len(changed) == 2 * 4  # four linear layers, weights and biases
        assert history[-1]["loss"] < 0.5 * history[0]["loss"]
        ends[dtype] = history[-1]["val_hole_mm"]
    assert ends[torch.bfloat16] == pytest.approx(ends[None], rel=0.2)


def test_the_spread_over_seeds_is_the_sample_mean_and_std():
    runs = ((0, 3.1, 0.001), (1, 3.9, 0.0), (2, 3.4, 0.002))
    metrics = {"cuikm": {s: {"hole_mm_mean": v, "hole_mm_p95": 3 * v, "collision_rate_paper": c,
                             "any_violation_share": c} for s, v, c in runs},
               "uikm": {5: {"hole_mm_mean": 0.9, "hole_mm_p95": 2.0, "collision_rate_paper": 0.25,
                            "any_violation_share": 0.2}}}
    table = seed_table(metrics, {"cuikm": 0, "uikm": 5})
    assert list(table["kept"]) == [True, False, False, True]
    spread = seed_spread(table)
    assert spread["cuikm"]["seeds"] == 3
    assert spread["cuikm"]["mean_mm_seed_mean"] == pytest.approx(np.mean([3.1, 3.9, 3.4]))
    assert spread["cuikm"]["mean_mm_seed_std"] == pytest.approx(np.std([3.1, 3.9, 3.4], ddof=1))
    assert spread["cuikm"]["collision_rate_pct_seed_std"] == pytest.approx(np.std([0.1, 0.0, 0.2], ddof=1))
    assert spread["uikm"] == {"seeds": 1, "mean_mm_seed_mean": 0.9, "mean_mm_seed_std": 0.0,
                              "collision_rate_pct_seed_mean": 25.0, "collision_rate_pct_seed_std": 0.0}


def test_seed_checkpoints_are_found_in_seed_order_and_nothing_else(tmp_path):
    folder = tmp_path / "cuikm_seeds"
    folder.mkdir()
    for name in ("cuikm_seed10.pt", "cuikm_seed2.pt", "cuikm_seed2_final.json", "uikm_seed1.pt", "cuikm_seedx.pt"):
        (folder / name).write_bytes(b"")
    assert list(seed_checkpoints(tmp_path, "cuikm")) == [2, 10]
    assert seed_checkpoints(tmp_path, "uikm") == {}  # no uikm_seeds folder


def test_the_report_gives_mean_and_std_where_there_are_seeds():
    base = {"hole_mm_mean": 3.2, "hole_mm_median": 1.2, "hole_mm_p95": 7.0, "hole_mm_max": 40.0,
            "direction_deg_mean": 0.01, "collision_rate_paper": 0.0006, "any_violation_share": 0.0006,
            "solve_ms_per_1000": 0.5}
    metrics = {"cuikm": {**base, "seeds": 3, "mean_mm_seed_mean": 3.456, "mean_mm_seed_std": 0.321,
                         "collision_rate_pct_seed_mean": 0.07, "collision_rate_pct_seed_std": 0.02},
               "uikm": dict(base)}
    text = render(metrics, pd.DataFrame(columns=["group", "method", "self", "wall", "ground", "arch"]), [])
    cuikm = next(line for line in text.splitlines() if line.startswith("| CUIKM"))
    uikm = next(line for line in text.splitlines() if line.startswith("| UIKM"))
    assert "3.46 ± 0.32 (3)" in cuikm and "0.07 ± 0.02 (3)" in cuikm
    assert "±" not in uikm and uikm.count("—") >= 2
