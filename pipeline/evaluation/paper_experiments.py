"""The baseline papers' own experiments (papers 001-003), as tables next to their numbers.

* paper 002 (PSO / EOPSO / CEOPSO) on huang9 and jumbo8: mean position / orientation error of
  the global best after 50 and 100 iterations, mean iterations to reach three accuracies, and
  CEOPSO's population-size table; targets are tool frames of random joint vectors;
* paper 003 (GA) on rescue6: its Table 3 poses with plain GA and with space decomposition;
* paper 001 (RBF) on jumbo8: joint errors on its 1 200 held-out samples and per-axis collar
  errors on the test groups.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import pandas as pd
import torch

from pipeline.assembly.build import load_boom
from pipeline.core.errors import ConfigError
from pipeline.core.settings import SEED_MAX, rule
from pipeline.data.hole_sets import MAX_TEST_GROUPS
from pipeline.evaluation.paper_numbers import PAPER_002
from pipeline.geometry.kinematics import Boom
from pipeline.optim.swarm import MAX_ITERATIONS, MAX_POPULATION
from pipeline.solvers.base import FrameTargets, HoleTargets, JointSpace, tool_transform
from pipeline.solvers.ga import GAParams, GeneticIK
from pipeline.solvers.nm import NMSolver
from pipeline.solvers.pso import ParticleSwarm, params_for
from pipeline.solvers.rbf import RBFSolver

log = logging.getLogger(__name__)


# The ``solver_benchmark.papers`` node (conf/solver_benchmark/default.yaml states the bounds): parsed with
# the solver_benchmark group and by paper_baselines first thing; a swarm's run is population x iterations
# boom poses, each run one target
@dataclass(frozen=True)
class PaperPSOSettings:
    booms: list[str] = field(metadata=rule(min_items=1, max_items=10))
    runs: int = field(metadata=rule(ge=1, le=10_000))  # targets, one swarm each
    iterations: int = field(metadata=rule(ge=1, le=MAX_ITERATIONS))
    checkpoints: list[int] = field(metadata=rule(ge=0, le=MAX_ITERATIONS, max_items=100))
    reach: list = field(metadata=rule(min_items=1, max_items=100))  # (position m, orientation rad) pairs
    populations: list[int] = field(metadata=rule(ge=2, le=MAX_POPULATION, max_items=20))
    population_boom: str
    seed: int = field(metadata=rule(ge=0, le=SEED_MAX))

    def __post_init__(self):
        for k, it in enumerate(self.checkpoints):
            if it > self.iterations:
                raise ConfigError(f"solver_benchmark.papers.pso.checkpoints[{k}] = {it}: beyond "
                                  f"solver_benchmark.papers.pso.iterations = {self.iterations}")


@dataclass(frozen=True)
class PaperGASettings:
    boom: str
    poses_deg: list = field(metadata=rule(min_items=1, max_items=100))  # joint vectors whose poses are targets
    generations: int = field(metadata=rule(ge=1, le=MAX_ITERATIONS))
    seed: int = field(metadata=rule(ge=0, le=SEED_MAX))


@dataclass(frozen=True)
class PaperRBFSettings:
    groups: list[int] = field(metadata=rule(ge=1, le=MAX_TEST_GROUPS, min_items=1, max_items=MAX_TEST_GROUPS))
    methods: list[str] = field(metadata=rule(min_items=1))  # solver_benchmark.solvers entries


@dataclass(frozen=True)
class PapersSettings:
    pso: PaperPSOSettings
    ga: PaperGASettings
    rbf: PaperRBFSettings


def random_frames(boom_name: str, n: int, seed: int) -> tuple[FrameTargets, Boom]:
    boom = load_boom(boom_name)
    space = JointSpace(boom)
    q = space.full(space.uniform((n,), torch.Generator().manual_seed(seed)))
    return FrameTargets.from_transforms(tool_transform(boom, q)), boom


def pso_experiments(cfg) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Paper 002 Figs. 5-7 and Table 3, as tables."""
    rows = []
    for boom_name in cfg.booms:
        targets, boom = random_frames(boom_name, int(cfg.runs), int(cfg.seed))
        for variant in ("pso", "eopso", "ceopso"):
            params = params_for(variant, {"iterations": int(cfg.iterations), "seed": int(cfg.seed)})
            solver = ParticleSwarm(boom, params)
            result = solver.solve(targets)
            tr = solver.trace
            row = {"boom": boom_name, "method": variant, "runs": len(targets), "wall_s": result.wall_s}
            for it in cfg.checkpoints:
                row[f"pos_mm_{it}"] = 1000 * float(tr.position[it].mean())
                row[f"ori_rad_{it}"] = float(tr.orientation[it].mean())
            for tol_p, tol_o in cfg.reach:
                first = tr.first_reach(tol_p, tol_o)
                ok = first >= 0
                key = f"{1000 * tol_p:g}mm_{tol_o:g}rad"
                row[f"reached_{key}"] = float(ok.double().mean())
                row[f"iters_{key}"] = float(first[ok].double().mean()) if ok.any() else math.nan
            rows.append(row)
            log.info("Huang et al. %s %s: %s", boom_name, variant, {k: round(v, 4) for k, v in row.items()
                                                                  if isinstance(v, float)})
    pop_rows = []
    targets, boom = random_frames(cfg.population_boom, int(cfg.runs), int(cfg.seed))
    tol_p, tol_o = cfg.reach[0]
    for pop in cfg.populations:
        solver = ParticleSwarm(boom, params_for("ceopso", {"population": int(pop), "iterations": int(cfg.iterations),
                                                           "seed": int(cfg.seed)}))
        solver.solve(targets)
        first = solver.trace.first_reach(tol_p, tol_o)
        ok = first >= 0
        its = first[ok].double()
        pop_rows.append({"boom": cfg.population_boom, "population": int(pop), "reached": float(ok.double().mean()),
                         "iters_mean": float(its.mean()) if ok.any() else math.nan,
                         "iters_var": float(its.var()) if ok.sum() > 1 else math.nan,
                         "paper_iters_mean": PAPER_002["population_iters"].get(int(pop), math.nan)})
    return pd.DataFrame(rows), pd.DataFrame(pop_rows)


def ga_experiments(cfg) -> pd.DataFrame:
    """Paper 003 Table 3: the four poses, plain GA and GA with space decomposition."""
    boom = load_boom(cfg.boom)
    q_true = torch.deg2rad(torch.tensor(list(cfg.poses_deg), dtype=torch.float64))
    targets = FrameTargets.from_transforms(tool_transform(boom, q_true))
    rows = []
    for decomposition in (False, True):
        solver = GeneticIK(boom, GAParams(decomposition=decomposition, generations=int(cfg.generations),
                                          seed=int(cfg.seed)))
        result = solver.solve(targets)
        for k in range(len(targets)):
            rows.append({
                "method": "GA + space decomposition" if decomposition else "GA",
                "pose": k + 1,
                "target_deg": [round(v, 2) for v in cfg.poses_deg[k]],
                "found_deg": [round(float(v), 2) for v in torch.rad2deg(result.q[k])],
                "target_mm": [round(float(v), 3) for v in 1000 * targets.position[k]],
                "position_error_mm": 1000 * float(result.errors["position"][k]),
                "orientation_error_deg": math.degrees(float(result.errors["orientation"][k])),
                "level": int(solver.level[k]),
                "wall_s": result.wall_s,
            })
    return pd.DataFrame(rows)


def rbf_experiment(specs: dict[str, dict], boom, poses: torch.Tensor, face: torch.Tensor, box) -> pd.DataFrame:
    """Paper 001's own figures for each RBF entry of ``specs`` (the paper's and the tuned one): joint
    errors on its held-out samples, per-axis collar errors on ``poses`` (the test groups), and on
    ``face`` (the 63 blast holes of the demo face) beside paper 000's NM on the same face."""
    rows = []
    for name, spec in specs.items():
        spec = {k: v for k, v in spec.items() if k not in ("kind", "max_holes")}
        solver = RBFSolver(boom, name=name, box=box if spec.pop("in_box", True) else None, **spec).fit()
        feats, x = solver.test_set
        rel = 100 * (solver.net(feats) - x).abs() / (solver.hi - solver.lo)
        fit_feats, fit_x = solver.fit_set
        rows += [
            _row(name, "spread", "spread used (tuned on the held-out samples where spreads are given)", solver.spread),
            _row(name, "fit_residual_max", "fit samples: max abs joint error (interpolation residual, rad or m)",
                 float((solver.net(fit_feats) - fit_x).abs().max())),
            _row(name, "heldout_joint_error_max_pct", "held-out samples: max joint error, % of the sampled range",
                 float(rel.max())),
            _row(name, "heldout_joint_error_mean_pct", "held-out samples: mean joint error, % of the sampled range",
                 float(rel.mean())),
        ]
        rows += _collar_rows(name, "test groups", solver, boom, poses)
        rows += _collar_rows(name, "63-hole face", solver, boom, face)
    rows += _collar_rows("nm", "63-hole face", NMSolver(boom, restarts=3), boom, face)
    return pd.DataFrame(rows)


def _row(method: str, key: str, what: str, value: float) -> dict:
    return {"method": method, "key": key, "what": what, "value": value}


def _collar_rows(method: str, where: str, solver, boom, poses: torch.Tensor) -> list[dict]:
    """Mean and max collar error per axis (mm) and the mean hole-seeking error of a solver on ``poses``."""
    result = solver.solve(HoleTargets(poses, boom.preview_depth))
    collar = (tool_transform(boom, result.q)[:, :3, 3] - poses[:, :3]).abs() * 1000
    tag = "face" if "face" in where else "test"
    rows = []
    for k, axis in enumerate("xyz"):
        rows.append(_row(method, f"{tag}_collar_{axis}_mean_mm", f"{where}: collar error {axis.upper()} mean (mm)",
                         float(collar[:, k].mean())))
        rows.append(_row(method, f"{tag}_collar_{axis}_max_mm", f"{where}: collar error {axis.upper()} max (mm)",
                         float(collar[:, k].max())))
    rows.append(_row(method, f"{tag}_hole_mm_mean", f"{where}: mean hole-seeking error (mm)",
                     1000 * float(result.errors["hole"].mean())))
    return rows


def paper_metrics(tables: dict[str, pd.DataFrame]) -> dict[str, float]:
    """The key figures of the experiments as flat MLflow metric names."""
    metrics = {}
    for r in tables["pso"].to_dict("records"):
        metrics.update({f"pso.{r['boom']}.{r['method']}.{k}": v for k, v in r.items()
                        if isinstance(v, float) and math.isfinite(v) and k != "wall_s"})
    for r in tables["ga"].to_dict("records"):
        tag = "ga_decomposition" if "decomposition" in r["method"] else "ga"
        metrics[f"{tag}.pose{r['pose']}.position_error_mm"] = r["position_error_mm"]
    metrics.update({f"{m}.{k}": v for m, k, v in zip(tables["rbf"]["method"], tables["rbf"]["key"],
                                                     tables["rbf"]["value"], strict=True) if math.isfinite(v)})
    return metrics
