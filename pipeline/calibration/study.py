"""The calibration study of paper 004 (stage ``calibrate``): kinematic error compensation against identification.

A true jumbo8 with per-joint geometric errors at each level of ``calibration.levels`` is measured
(collar + direction, sensor noise) at face-like joint vectors. From the first ``n`` measurements,
paper 004's BP / PSO-BP / SSA-BP networks learn theta -> q, and Levenberg-Marquardt identifies the
error twists. Held-out face holes are then solved on the nominal model (the networks correct the
joints) or on the identified model, executed on the true boom, and the collar and direction errors
are reported. Also the fit of a field measurement file (``fit_file``). Settings: :class:`CalibrationSettings`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import pandas as pd
import torch
from omegaconf import DictConfig

from pipeline.assembly.build import build_safety
from pipeline.calibration.compensation import INITS, NetworkParams, fit_compensator, training_pairs
from pipeline.calibration.error_model import DISTRIBUTIONS, BoomWithErrors, ErrorLevel, draw_errors
from pipeline.calibration.identification import Basis, Weights, identifiable_basis, identify
from pipeline.calibration.ik import solve_holes
from pipeline.calibration.measurements import (
    ANGLE_UNITS,
    LENGTH_UNITS,
    Measurements,
    Sensor,
    read_measurements,
    simulate,
)
from pipeline.calibration.model_file import save_model
from pipeline.calibration.quality import GateSettings, assess, rejected_path, rejection_message, write_rejected
from pipeline.calibration.swarm import PSOParams, SSAParams
from pipeline.core.config import project_path
from pipeline.core.errors import ConfigError, Diverged, InputError
from pipeline.core.io import save_figure, write_csv, write_text
from pipeline.core.settings import SEED_MAX, parse, rule
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.evaluation.markdown import markdown_table
from pipeline.evaluation.plots import calibration_figure
from pipeline.geometry.collision import SafetyModel
from pipeline.solvers.base import HoleTargets

log = logging.getLogger(__name__)

METHODS = ("uncompensated", *INITS, "identification")
# Bounds (conf/calibration/default.yaml): ten times the paper's 1 000 measured poses, each an NM solve and five
# equations of LM (whose Jacobian also spans the network's weights); the held-out and basis poses are NM solves too
MAX_MEASUREMENTS = 10_000
MAX_POSES = 100_000
COLUMNS = ["method", "level", "n_measurements", "collar_mm_mean", "collar_mm_max", "direction_deg_mean",
           "collar_mm_p95", "direction_deg_max", "hole_mm_mean", "any_violation_share", "samples", "fit_s", "note"]


@dataclass(frozen=True)
class Seeds:
    """``calibration.seeds``: none shared with holes (0, 1, 101-105) or train (999)."""

    errors: int = field(default=13, metadata=rule(ge=0, le=SEED_MAX))  # the true boom's error twists
    # face holes whose nominal IK solutions are measured
    poses: int = field(default=1301, metadata=rule(ge=0, le=SEED_MAX))
    noise: int = field(default=1302, metadata=rule(ge=0, le=SEED_MAX))  # sensor noise
    holdout: int = field(default=1303, metadata=rule(ge=0, le=SEED_MAX))  # the held-out face holes
    network: int = field(default=1304, metadata=rule(ge=0, le=SEED_MAX))  # BP initial weights and the swarms


@dataclass(frozen=True)
class IKSettings:
    """``calibration.ik``: paper 000's NM on the nominal or identified model."""

    max_iters: int = field(default=100, metadata=rule(ge=1, le=10_000))
    tol: float = field(default=1e-7, metadata=rule(gt=0))  # |pose6 residual| (m)
    damping: float = field(default=1e-3, metadata=rule(gt=0))
    restarts: int = field(default=0, metadata=rule(ge=0, le=1000))
    pair_tol: float = field(default=1e-6, metadata=rule(gt=0))  # a training pair must reach its pose within this (m)


@dataclass(frozen=True)
class SwarmSettings:
    """``calibration.swarm``: initial BP weights for PSO-BP / SSA-BP."""

    pso: PSOParams = field(default_factory=PSOParams)
    ssa: SSAParams = field(default_factory=SSAParams)


@dataclass(frozen=True)
class IdentificationSettings:
    weights: Weights = field(default_factory=Weights)
    max_iters: int = field(default=50, metadata=rule(ge=1, le=10_000))
    basis_poses: int = field(default=200, metadata=rule(ge=1, le=MAX_POSES))
    max_condition: float = field(default=1e8, metadata=rule(gt=0))


@dataclass(frozen=True)
class FileUnits:
    """``calibration.file_units``: units of a measurement file's joints and collar."""

    angle: str = field(default="rad", metadata=rule(choices=tuple(ANGLE_UNITS)))
    length: str = field(default="m", metadata=rule(choices=tuple(LENGTH_UNITS)))


@dataclass(frozen=True)
class CalibrationSettings:
    """The ``calibration`` group (conf/calibration/default.yaml); ``levels`` become :class:`ErrorLevel` s."""

    levels: dict  # name -> error level (calibration/level/*.yaml)
    sensor: Sensor  # calibration/sensor/*.yaml
    model_file: str
    run_levels: list[str] = field(default_factory=lambda: ["paper", "field"], metadata=rule(min_items=1))
    methods: list[str] = field(default_factory=lambda: list(METHODS), metadata=rule(choices=METHODS, min_items=1))
    n_measurements: list[int] = field(default_factory=lambda: [10, 30, 100, 1000],
                                      metadata=rule(ge=2, le=MAX_MEASUREMENTS, min_items=1, max_items=20))
    holdout: int = field(default=1000, metadata=rule(ge=1, le=MAX_POSES))
    error_distribution: str = field(default="sign", metadata=rule(choices=DISTRIBUTIONS))
    seeds: Seeds = field(default_factory=Seeds)
    ik: IKSettings = field(default_factory=IKSettings)
    network: NetworkParams = field(default_factory=NetworkParams)
    swarm: SwarmSettings = field(default_factory=SwarmSettings)
    identification: IdentificationSettings = field(default_factory=IdentificationSettings)
    file_units: FileUnits = field(default_factory=FileUnits)
    gate: GateSettings = field(default_factory=GateSettings)  # the field fit's quality gate

    def __post_init__(self):
        levels = {str(k): parse(ErrorLevel, v, f"calibration.levels.{k}") for k, v in dict(self.levels).items()}
        object.__setattr__(self, "levels", levels)
        missing = [lv for lv in self.run_levels if lv not in levels]
        if missing:
            raise ConfigError(f"calibration.run_levels = {list(self.run_levels)}: {missing} not among "
                              f"calibration.levels {list(levels)}")


@dataclass
class Setup:
    """What every level shares: the nominal boom, the measured joint vectors, the held-out holes."""

    safety: SafetyModel
    q_measured: torch.Tensor  # (n_max, n_joints): nominal IK solutions of face holes
    holdout: torch.Tensor  # (holdout, 6) hole poses
    theta_holdout: torch.Tensor  # their nominal IK solutions
    basis: Basis


def _ik_kwargs(ik) -> dict:
    return {"max_iters": int(ik.max_iters), "tol": float(ik.tol), "damping": float(ik.damping)}


def face_holes(safety: SafetyModel, sampling: HoleSampling, n: int, seed: int, ik) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` drillable face holes ``(n, 6)`` and their nominal NM solutions ``(n, n_joints)``: the
    joint vectors a rig uses at the face. Holes NM does not reach are skipped (a few extra are drawn),
    so no method is charged for a failure of the nominal IK."""
    pose, _ = sample_holes(n + 10 + n // 10, safety, sampling, seed)
    q, err = solve_holes(safety.boom, pose, restarts=int(ik.restarts), seed=seed, **_ik_kwargs(ik))
    reached = err <= float(ik.tol)
    if int(reached.sum()) < n:
        raise InputError(f"calibration: NM reached only {int(reached.sum())} of {len(pose)} face holes (seed {seed}); "
                         f"{n} are needed: raise calibration.ik.restarts or max_iters")
    return pose[reached][:n], q[reached][:n]


def residual_errors(true_boom: BoomWithErrors, safety: SafetyModel, q: torch.Tensor, pose: torch.Tensor) -> dict:
    """Joints ``q`` executed on the true boom against the holes they were solved for (mm, deg)."""
    with torch.no_grad():
        frames = true_boom.frames(q)
        err = HoleTargets(pose, true_boom.preview_depth).errors(frames[:, true_boom.tool_index])
        true_safety = SafetyModel(true_boom, safety.tunnel, safety.distances, safety.points_per_capsule, safety.exact)
        clear = true_safety.clearances_from_frames(frames)
    collar, direction = 1e3 * err["position"], torch.rad2deg(err["orientation"])
    violated = torch.stack([c < 0 for c in clear.values()]).any(0)
    return {
        "collar_mm_mean": float(collar.mean()), "collar_mm_max": float(collar.max()),
        "direction_deg_mean": float(direction.mean()), "collar_mm_p95": float(collar.quantile(0.95)),
        "direction_deg_max": float(direction.max()), "hole_mm_mean": float(1e3 * err["hole"].mean()),
        "any_violation_share": float(violated.double().mean()),
    }


def run_level(name: str, level: ErrorLevel, setup: Setup,
              ccfg: CalibrationSettings) -> tuple[list[dict], BoomWithErrors, dict]:
    """Every method at every n for one error level; also the true boom and the largest-n fits."""
    nominal = setup.safety.boom
    true_boom = BoomWithErrors(nominal, draw_errors(nominal, level, int(ccfg.seeds.errors), ccfg.error_distribution))
    measured = simulate(true_boom, setup.q_measured, ccfg.sensor, int(ccfg.seeds.noise))
    ik = _ik_kwargs(ccfg.ik)
    methods = list(ccfg.methods)
    nets = [m for m in methods if m in INITS]
    if nets:
        theta, q, ok = training_pairs(nominal, measured, pair_tol=float(ccfg.ik.pair_tol), **ik)
    net_params, pso, ssa = ccfg.network, ccfg.swarm.pso, ccfg.swarm.ssa
    weights = ccfg.identification.weights
    base = residual_errors(true_boom, setup.safety, setup.theta_holdout, setup.holdout)
    rows, fits = [], {}
    for n in sorted(int(v) for v in ccfg.n_measurements):
        common = {"level": name, "n_measurements": n}
        if "uncompensated" in methods:
            rows.append({"method": "uncompensated", **common, **base, "samples": 0, "fit_s": 0.0, "note": ""})
        for method in nets:
            use = ok[:n]
            comp = fit_compensator(theta[:n][use], q[:n][use], net_params, method, int(ccfg.seeds.network), pso, ssa)
            res = residual_errors(true_boom, setup.safety, comp(setup.theta_holdout), setup.holdout)
            info = comp.info
            rows.append({"method": method, **common, **res, "samples": info["samples"], "fit_s": info["fit_s"],
                         "note": f"train mse {info['mse_init']:.3g} -> {info['mse']:.3g} in {info['iterations']} it"})
        if "identification" in methods:
            start = time.perf_counter()
            try:
                fit = identify(nominal, measured.subset(slice(0, n)), setup.basis, weights,
                               int(ccfg.identification.max_iters),
                               max_condition=float(ccfg.identification.max_condition))
            except (InputError, Diverged) as exc:  # too few / degenerate measurements: said in the table, no silent NaN
                log.warning("identification, level %s, n = %d: %s", name, n, exc)
                nan = dict.fromkeys(COLUMNS[3:11], math.nan)
                rows.append({"method": "identification", **common, **nan, "samples": n, "fit_s": 0.0,
                             "note": f"not identifiable: {exc}"})
                continue
            fit_s = time.perf_counter() - start
            model = BoomWithErrors(nominal, fit.twists)
            q_hat, _ = solve_holes(model, setup.holdout, start=setup.theta_holdout, restarts=int(ccfg.ik.restarts),
                                   seed=int(ccfg.seeds.holdout), **ik)
            res = residual_errors(true_boom, setup.safety, q_hat, setup.holdout)
            rows.append({"method": "identification", **common, **res, "samples": n,
                         "fit_s": fit_s,
                         "note": f"rank {fit.rank}/{len(setup.basis.names)}, cond {fit.condition:.3g}, fit rms "
                                 f"{fit.collar_rms_mm:.3g} mm / {fit.direction_rms_deg:.3g} deg"})
            fits[n] = fit
        for r in rows[-len(methods):]:
            log.info("%-6s n=%-5d %-14s collar %.4g mm (max %.4g), direction %.4g deg", name, n, r["method"],
                     r["collar_mm_mean"], r["collar_mm_max"], r["direction_deg_mean"])
    return rows, true_boom, fits


def build_setup(cfg: DictConfig, ccfg: CalibrationSettings) -> Setup:
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    sampling = HoleSampling(tuple(cfg.holes.face_x), float(cfg.holes.cone_deg), float(cfg.holes.inset))
    n_max = max(int(v) for v in ccfg.n_measurements)
    _, q_measured = face_holes(safety, sampling, n_max, int(ccfg.seeds.poses), ccfg.ik)
    holdout, theta = face_holes(safety, sampling, int(ccfg.holdout), int(ccfg.seeds.holdout), ccfg.ik)
    log.info("measured joint vectors: %d; held-out holes: %d (nominal NM solutions of face holes)",
             len(q_measured), len(holdout))
    basis = identifiable_basis(safety.boom, ccfg.identification.weights,
                               int(ccfg.identification.basis_poses), seed=int(ccfg.seeds.poses))
    return Setup(safety, q_measured, holdout, theta, basis)


def markdown(df: pd.DataFrame) -> str:
    cols = ["method", "level", "n_measurements", "collar_mm_mean", "collar_mm_max", "direction_deg_mean"]
    return markdown_table(df[cols], digits=3, nan="—")  # a fit that failed: a dash, its reason in results.csv


def run_study(cfg: DictConfig, ccfg: CalibrationSettings, mlrun) -> pd.DataFrame:
    """The study at every level of ``run_levels``: tables, figure, models, identifiability report; metrics
    and artifacts to ``mlrun`` (anything with ``log_metrics``, ``log_table``, ``log_figure``, ``log_artifact``)."""
    out = project_path(cfg.paths.data) / "calibration"
    start = time.perf_counter()
    setup = build_setup(cfg, ccfg)
    rows = []
    written = []
    for name in ccfg.run_levels:
        level = ccfg.levels[name]
        level_rows, true_boom, fits = run_level(name, level, setup, ccfg)
        rows += level_rows
        nominal = setup.safety.boom
        save_model(out / "models" / f"true_{name}.yaml", nominal, true_boom.twists,
                   fit={"level": name, "seed": int(ccfg.seeds.errors), "distribution": ccfg.error_distribution})
        written.append(out / "models" / f"true_{name}.yaml")
        if fits:
            n, fit = max(fits.items())
            path = out / "models" / f"identified_{name}.yaml"
            save_model(path, nominal, fit.twists, setup.basis.kept_names,
                       {"n_measurements": n, "collar_rms_mm": fit.collar_rms_mm,
                        "direction_rms_deg": fit.direction_rms_deg, "rank": fit.rank, "condition": fit.condition},
                       setup.basis.describe())
            written.append(path)
    df = pd.DataFrame(rows, columns=COLUMNS)
    wall = time.perf_counter() - start
    write_csv(df, out / "results.csv")
    write_text(f"Residual errors on {int(ccfg.holdout)} held-out face holes executed on the true boom; sensor "
               f"{ccfg.sensor.position_mm} mm / {ccfg.sensor.direction_deg} deg; {wall:.0f} s.\n\n" + markdown(df),
               out / "results.md")
    basis = setup.basis
    write_text(f"# Identifiable error parameters of {setup.safety.boom.name} (collar + direction measured)\n\n"
               f"{len(basis.kept)} of {len(basis.names)} kept (condition number {basis.condition:.3g} at "
               f"{int(ccfg.identification.basis_poses)} generic poses):\n\n" + ", ".join(basis.kept_names)
               + "\n\nDropped, and how each merges into the kept ones (first order):\n\n"
               + "".join(f"- {line}\n" for line in basis.describe()), out / "identifiability.md")
    fig = calibration_figure(df)
    save_figure(fig, out / "figures" / "residual_vs_measurements.png")
    log.info("calibration study: %d rows in %.0f s -> %s", len(df), wall, out)
    mlrun.log_metrics({**{f"{r['level']}.{r['method']}.n{r['n_measurements']}.{k}": r[k]
                          for r in rows for k in ("collar_mm_mean", "collar_mm_max", "direction_deg_mean")},
                       "wall_s": wall})
    mlrun.log_table(df, "tables/calibration.json")
    mlrun.log_figure(fig, "figures/residual_vs_measurements.png")
    for path in [out / "results.csv", out / "identifiability.md", *written]:
        mlrun.log_artifact(path, "calibration")
    return df


def fit_file(cfg: DictConfig, ccfg: CalibrationSettings, mlrun):
    """Fit the identified model to a measurement file and write it to ``calibration.model_file`` when
    it passes the quality gate (:mod:`pipeline.calibration.quality`); a rejected fit raises."""
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    nominal = safety.boom
    path = project_path(cfg.measurements)
    meas: Measurements = read_measurements(path, nominal, ccfg.file_units.angle, ccfg.file_units.length)
    weights = ccfg.identification.weights
    basis = identifiable_basis(nominal, weights, int(ccfg.identification.basis_poses), seed=int(ccfg.seeds.poses))
    max_iters, max_condition = int(ccfg.identification.max_iters), float(ccfg.identification.max_condition)
    fit = identify(nominal, meas, basis, weights, max_iters, max_condition=max_condition)
    out = project_path(ccfg.model_file)
    summary = {"measurements": str(path), "n_measurements": len(meas), "collar_rms_mm": fit.collar_rms_mm,
               "direction_rms_deg": fit.direction_rms_deg, "rank": fit.rank, "condition": fit.condition}
    report = assess(nominal, meas, basis, weights, fit, ccfg.gate, max_iters, max_condition)
    mlrun.log_metrics({k: float(v) for k, v in summary.items() if k != "measurements" and math.isfinite(v)})
    mlrun.log_metrics({f"gate.{r.name}": r.value for r in report.rules if math.isfinite(r.value)})
    mlrun.set_tags({"calibration.gate": "accepted" if report.accepted else "rejected: " + ", ".join(report.failed)})
    for text in report.warnings:
        log.warning("%s: %s", path, text)
    if not report.accepted:  # the current model stays; the report goes beside it
        write_rejected(out, report, summary)
        mlrun.log_artifact(rejected_path(out), "calibration")
        raise InputError(rejection_message(str(path), report, rejected_path(out)))
    save_model(out, nominal, fit.twists, basis.kept_names, {**summary, "gate": report.as_dict()}, basis.describe())
    rejected_path(out).unlink(missing_ok=True)  # a report of an earlier rejected fit no longer describes this model
    log.info("identified %d parameters from %d measurements of %s: residual rms %.3g mm / %.3g deg -> %s",
             fit.rank, len(meas), path, fit.collar_rms_mm, fit.direction_rms_deg, out)
    mlrun.log_artifact(out, "calibration")
    return fit
