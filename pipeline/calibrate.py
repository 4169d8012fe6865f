"""Stage ``calibrate`` (issue 13, paper 004): kinematic error compensation against identification.

    python -m pipeline.calibrate                                  # the study -> paths.data/calibration/
    python -m pipeline.calibrate measurements=field.csv           # fit a measurement file -> calibration.model_file

The study: a true jumbo8 with per-joint geometric errors at each level of ``calibration.levels``
is measured (collar + direction, sensor noise) at face-like joint vectors. From the first ``n``
measurements, paper 004's BP / PSO-BP / SSA-BP networks learn theta -> q, and Levenberg-Marquardt
identifies the error twists. Held-out face holes are then solved on the nominal model (the
networks correct the joints) or on the identified model, executed on the true boom, and the
collar and direction errors are reported. Writes ``results.csv`` / ``results.md``, the figure,
the true and identified models and the identifiability report, and logs them to MLflow.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import hydra
import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.assembly.build import build_safety
from pipeline.calibration.compensation import INITS, NetworkParams, fit_compensator, training_pairs
from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors
from pipeline.calibration.identification import Basis, Weights, identifiable_basis, identify
from pipeline.calibration.ik import solve_holes
from pipeline.calibration.measurements import Measurements, Sensor, read_measurements, simulate
from pipeline.calibration.model_file import save_model
from pipeline.calibration.swarm import PSOParams, SSAParams
from pipeline.core.config import project_path
from pipeline.core.device import configure_process
from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import save_figure, write_csv, write_text
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.evaluation.plots import calibration_figure
from pipeline.geometry.collision import SafetyModel
from pipeline.solvers.base import HoleTargets
from pipeline.tracking.runs import StageRun, TrackingSettings, stage_run

log = logging.getLogger(__name__)

METHODS = ("uncompensated", *INITS, "identification")
COLUMNS = ["method", "level", "n_measurements", "collar_mm_mean", "collar_mm_max", "direction_deg_mean",
           "collar_mm_p95", "direction_deg_max", "hole_mm_mean", "any_violation_share", "samples", "fit_s", "note"]


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
        true_safety = SafetyModel(true_boom, safety.tunnel, safety.distances, safety.n_points)
        clear = true_safety.clearances_from_frames(frames)
    collar, direction = 1e3 * err["position"], torch.rad2deg(err["orientation"])
    violated = torch.stack([c < 0 for c in clear.values()]).any(0)
    return {
        "collar_mm_mean": float(collar.mean()), "collar_mm_max": float(collar.max()),
        "direction_deg_mean": float(direction.mean()), "collar_mm_p95": float(collar.quantile(0.95)),
        "direction_deg_max": float(direction.max()), "hole_mm_mean": float(1e3 * err["hole"].mean()),
        "any_violation_share": float(violated.double().mean()),
    }


def run_level(name: str, level: ErrorLevel, setup: Setup, ccfg) -> tuple[list[dict], BoomWithErrors, dict]:
    """Every method at every n for one error level; also the true boom and the largest-n fits."""
    nominal = setup.safety.boom
    true_boom = BoomWithErrors(nominal, draw_errors(nominal, level, int(ccfg.seeds.errors), ccfg.error_distribution))
    measured = simulate(true_boom, setup.q_measured, Sensor(**ccfg.sensor), int(ccfg.seeds.noise))
    ik = _ik_kwargs(ccfg.ik)
    methods = list(ccfg.methods)
    nets = [m for m in methods if m in INITS]
    if nets:
        theta, q, ok = training_pairs(nominal, measured, pair_tol=float(ccfg.ik.pair_tol), **ik)
    net_params = NetworkParams(**OmegaConf.to_container(ccfg.network, resolve=True))
    pso, ssa = PSOParams(**ccfg.swarm.pso), SSAParams(**ccfg.swarm.ssa)
    weights = Weights(**ccfg.identification.weights)
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
            except InputError as exc:  # too few / degenerate measurements: say so in the table, no silent NaN
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


def build_setup(cfg: DictConfig) -> Setup:
    ccfg = cfg.calibration
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    sampling = HoleSampling(tuple(cfg.holes.face_x), float(cfg.holes.cone_deg), float(cfg.holes.inset))
    n_max = max(int(v) for v in ccfg.n_measurements)
    _, q_measured = face_holes(safety, sampling, n_max, int(ccfg.seeds.poses), ccfg.ik)
    holdout, theta = face_holes(safety, sampling, int(ccfg.holdout), int(ccfg.seeds.holdout), ccfg.ik)
    log.info("measured joint vectors: %d; held-out holes: %d (nominal NM solutions of face holes)",
             len(q_measured), len(holdout))
    basis = identifiable_basis(safety.boom, Weights(**ccfg.identification.weights),
                               int(ccfg.identification.basis_poses), seed=int(ccfg.seeds.poses))
    return Setup(safety, q_measured, holdout, theta, basis)


def check_config(ccfg) -> None:
    unknown = [m for m in ccfg.methods if m not in METHODS]
    if unknown or not len(ccfg.methods):
        raise ConfigError(f"calibration.methods = {list(ccfg.methods)}: expected a non-empty subset of {list(METHODS)}")
    missing = [lv for lv in ccfg.run_levels if lv not in ccfg.levels]
    if missing or not len(ccfg.run_levels):
        raise ConfigError(f"calibration.run_levels = {list(ccfg.run_levels)}: expected names from "
                          f"calibration.levels {list(ccfg.levels)}")
    ns = list(ccfg.n_measurements)
    if not ns or any(isinstance(n, bool) or not isinstance(n, int) or n < 2 for n in ns):
        raise ConfigError(f"calibration.n_measurements = {ns}: expected integers >= 2")
    if int(ccfg.holdout) < 1:
        raise ConfigError(f"calibration.holdout = {ccfg.holdout}: expected a positive integer")


def markdown(df: pd.DataFrame) -> str:
    cols = ["method", "level", "n_measurements", "collar_mm_mean", "collar_mm_max", "direction_deg_mean"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in df[cols].itertuples(index=False):
        cells = [str(v) if isinstance(v, (str, int)) else ("—" if math.isnan(v) else f"{v:.3g}") for v in r]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def run_study(cfg: DictConfig, mlrun: StageRun) -> pd.DataFrame:
    ccfg = cfg.calibration
    out = project_path(cfg.paths.data) / "calibration"
    start = time.perf_counter()
    setup = build_setup(cfg)
    rows = []
    written = []
    for name in ccfg.run_levels:
        level = ErrorLevel(**ccfg.levels[name])
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


def fit_file(cfg: DictConfig, mlrun: StageRun):
    """Fit the identified model to a measurement file and write it to ``calibration.model_file``."""
    ccfg = cfg.calibration
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    nominal = safety.boom
    path = project_path(cfg.measurements)
    meas: Measurements = read_measurements(path, nominal, ccfg.file_units.angle, ccfg.file_units.length)
    weights = Weights(**ccfg.identification.weights)
    basis = identifiable_basis(nominal, weights, int(ccfg.identification.basis_poses), seed=int(ccfg.seeds.poses))
    fit = identify(nominal, meas, basis, weights, int(ccfg.identification.max_iters),
                   max_condition=float(ccfg.identification.max_condition))
    out = project_path(ccfg.model_file)
    summary = {"measurements": str(path), "n_measurements": len(meas), "collar_rms_mm": fit.collar_rms_mm,
               "direction_rms_deg": fit.direction_rms_deg, "rank": fit.rank, "condition": fit.condition}
    save_model(out, nominal, fit.twists, basis.kept_names, summary, basis.describe())
    log.info("identified %d parameters from %d measurements of %s: residual rms %.3g mm / %.3g deg -> %s",
             fit.rank, len(meas), path, fit.collar_rms_mm, fit.direction_rms_deg, out)
    mlrun.log_metrics({k: float(v) for k, v in summary.items() if k != "measurements"})
    mlrun.log_artifact(out, "calibration")
    return fit


def run(cfg: DictConfig):
    """The study (default), or the fit of a measurement file (``measurements=<file>``)."""
    tracking = TrackingSettings.from_config(cfg.tracking)
    check_config(cfg.calibration)
    fitting = bool(cfg.get("measurements"))
    if fitting and not project_path(cfg.measurements).is_file():  # before any run exists
        raise InputError(f"measurements = {cfg.measurements}: no such file")
    with stage_run(tracking, "calibrate-fit" if fitting else "calibrate", {"stage": "calibrate"}) as mlrun:
        mlrun.log_params({"calibration": OmegaConf.to_container(cfg.calibration, resolve=True),
                          "measurements": str(cfg.get("measurements"))})
        return fit_file(cfg, mlrun) if fitting else run_study(cfg, mlrun)


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    configure_process(cfg.calibration.threads)  # one thread: see conf/calibration/default.yaml
    run(cfg)


if __name__ == "__main__":
    main()
