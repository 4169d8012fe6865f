"""The quality gate of a field calibration: a fitted boom model is accepted only when the fit can be
trusted, because ``solve boom_model=`` then calls holes exact for that model, not for the boom.

Rules (``calibration.gate``; docs/calibration.md, "The quality gate"):

1. **rank**: the measurements identify the whole basis (:func:`identify` refuses otherwise).
2. **poses**: at least ``min_equation_ratio`` times as many equations (5 per pose: collar 3,
   direction 2) as identified parameters, so the fit cannot follow the noise.
3. **noise**: the weighted residual, ``sqrt(cost / (equations - parameters))``, is about 1 when the
   model explains the data to the instrument's 1 sigma (``calibration.identification.weights``).
   Far above: a bad file (units, swapped columns, a slipped joint reading); far below: overfitting,
   or an instrument better than the weights claim. It must lie in ``residual_ratio``.
4. **held-out**: a ``folds``-fold check fits on the other poses and predicts each fold; the held-out
   weighted residual may exceed the training one by at most ``holdout_factor``.

A rejected fit never replaces the current model: :func:`write_rejected` writes a report beside it
naming each failed rule and the likely cause.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import yaml

from pipeline.calibration.error_model import DTYPE, BoomWithErrors
from pipeline.calibration.identification import EQUATIONS_PER_MEASUREMENT, Basis, Identification, Weights, identify
from pipeline.calibration.measurements import Measurements
from pipeline.core.errors import ConfigError, Diverged, InputError
from pipeline.core.io import write_text
from pipeline.core.settings import parse, rule
from pipeline.geometry.kinematics import Boom


@dataclass(frozen=True)
class GateSettings:
    """The ``calibration.gate`` config node."""

    min_equation_ratio: float = field(default=3.0, metadata=rule(ge=1))
    residual_ratio: tuple[float, ...] = field(default=(0.33, 3.0), metadata=rule(ge=0))
    folds: int = field(default=5, metadata=rule(ge=2, le=100))  # each a fit of the other poses
    holdout_factor: float = field(default=2.0, metadata=rule(gt=1))
    duplicates: str = field(default="refuse", metadata=rule(choices=("refuse", "warn")))

    def __post_init__(self):
        lo_hi = self.residual_ratio
        if len(lo_hi) != 2 or not lo_hi[0] < 1 < lo_hi[1]:
            raise ConfigError(f"calibration.gate.residual_ratio = {list(lo_hi)}: expected [lower, upper] "
                              "with lower < 1 < upper")

    @classmethod
    def from_config(cls, node) -> GateSettings:
        return parse(cls, node, "calibration.gate")


@dataclass
class RuleResult:
    name: str
    passed: bool
    value: float
    limit: str
    detail: str


@dataclass
class GateReport:
    rules: list[RuleResult]
    causes: list[str]
    warnings: list[str]

    @property
    def accepted(self) -> bool:
        return all(r.passed for r in self.rules)

    @property
    def failed(self) -> list[str]:
        return [r.name for r in self.rules if not r.passed]

    def as_dict(self) -> dict:
        return {"accepted": self.accepted,
                "rules": {r.name: {"passed": r.passed, "value": _plain(r.value), "limit": r.limit, "detail": r.detail}
                          for r in self.rules},
                "likely_causes": self.causes, "warnings": self.warnings}


def _plain(v: float) -> float | str:
    return float(v) if math.isfinite(v) else str(v)  # YAML readers differ on .inf


def duplicate_rows(meas: Measurements, rtol: float = 1e-9) -> list[list[int]]:
    """Groups (0-based rows) of measurements taken at the same joint vector."""
    q = meas.q.to(DTYPE)
    scale = q.abs().amax(0).clamp_min(1.0)
    close = ((q[:, None, :] - q[None, :, :]).abs() <= rtol * scale).all(-1)  # (N, N): pairs, fine for field sizes
    groups, seen = [], set()
    for i in range(len(meas)):
        if i in seen:
            continue
        same = close[i].nonzero().flatten().tolist()
        if len(same) > 1:
            groups.append(same)
            seen.update(same)
    return groups


def weighted_residuals(boom: Boom, twists: torch.Tensor, meas: Measurements, weights: Weights) -> torch.Tensor:
    """Per pose, the squared residual in instrument sigmas: collar distance over the position sigma
    and direction angle over the direction sigma (the identification's residual, 5 equations)."""
    p, z = BoomWithErrors(boom, twists).tool_pose(meas.q.to(DTYPE))
    collar = (p - meas.collar).norm(dim=-1) / (1e-3 * weights.position_mm)
    angle = torch.atan2(torch.linalg.cross(z, meas.direction, dim=-1).norm(dim=-1), (z * meas.direction).sum(-1))
    return collar.square() + (angle / math.radians(weights.direction_deg)).square()


def _training_ratio(fit: Identification, n: int, k: int) -> float:
    dof = n * EQUATIONS_PER_MEASUREMENT - k
    cost = fit.history[-1] if fit.history else math.inf
    return math.sqrt(cost / dof) if dof > 0 and math.isfinite(cost) else math.inf


def _holdout_ratio(boom: Boom, meas: Measurements, basis: Basis, weights: Weights, folds: int, max_iters: int,
                   max_condition: float) -> tuple[float, str]:
    """Held-out weighted residual over every fold (each predicted by a fit on the others)."""
    n = len(meas)
    order = torch.randperm(n, generator=torch.Generator().manual_seed(0))
    squared = torch.empty(n, dtype=DTYPE)
    for f in range(folds):
        held = order[f::folds]
        keep = torch.ones(n, dtype=torch.bool)
        keep[held] = False
        try:
            fold_fit = identify(boom, meas.subset(keep), basis, weights, max_iters, max_condition=max_condition)
        except (InputError, Diverged) as exc:
            return math.inf, f"fold {f + 1} of {folds} cannot be identified without its poses ({exc})"
        squared[held] = weighted_residuals(boom, fold_fit.twists, meas.subset(held), weights)
    ratio = math.sqrt(float(squared.mean()) / EQUATIONS_PER_MEASUREMENT)
    return (ratio if math.isfinite(ratio) else math.inf), f"{folds}-fold"


def likely_causes(meas: Measurements, rules: list[RuleResult], residual: torch.Tensor) -> list[str]:
    """Plain-language guesses from the data, for the failed rules."""
    failed = {r.name for r in rules if not r.passed}
    norms = meas.collar.norm(dim=-1)
    median = float(norms.median())
    causes = []
    if median > 100:
        causes.append(f"collars look like millimetres (median distance from the base {median:.4g} m): set "
                      "calibration.file_units.length=mm or convert the collar columns to metres")
    elif 0.5 < median < 1.5:
        causes.append("the collar columns hold unit-length vectors: are the collar and direction columns swapped?")
    far = (~torch.isfinite(norms)) | (norms > 1e3)
    if far.any():
        rows = (far.nonzero().flatten() + 1).tolist()[:5]
        causes.append(f"collars far outside any boom's reach (> 1 km) at row(s) {rows}")
    if "poses" in failed:
        causes.append("too few poses for the parameters: the fit follows the noise; measure more distinct poses")
    noise = next((r for r in rules if r.name == "noise"), None)
    if noise is not None and not noise.passed and noise.value < 1:
        causes.append("the residual is below the instrument's noise: overfitting (too few poses), or "
                      "calibration.identification.weights claim a noisier instrument than the one used")
    if ({"noise", "holdout"} & failed) and not causes and torch.isfinite(residual).all():
        worst = (residual.argsort(descending=True)[:3] + 1).tolist()
        causes.append(f"a few readings are far off: the worst rows are {worst} (lines {[r + 1 for r in worst]}); "
                      "check those joint readings and prisms (a slipped encoder or a unit mix-up in one column)")
    return causes


def assess(boom: Boom, meas: Measurements, basis: Basis, weights: Weights, fit: Identification,
           settings: GateSettings, max_iters: int = 50, max_condition: float = 1e8) -> GateReport:
    """Check ``fit`` (of ``meas`` on ``basis``) against the gate's rules."""
    n, k = len(meas), len(basis.kept)
    equations = n * EQUATIONS_PER_MEASUREMENT
    rules = [RuleResult("rank", fit.rank == k, float(fit.rank), f"= {k}",
                        f"rank {fit.rank} of {k} identifiable parameters, condition {fit.condition:.3g}")]
    need = math.ceil(settings.min_equation_ratio * k / EQUATIONS_PER_MEASUREMENT)
    rules.append(RuleResult("poses", equations >= settings.min_equation_ratio * k, equations / k,
                            f">= {settings.min_equation_ratio:g} equations per parameter",
                            f"{n} poses give {equations} equations for {k} parameters; at least {need} poses"))
    lo, hi = settings.residual_ratio
    ratio = _training_ratio(fit, n, k)
    rules.append(RuleResult("noise", lo <= ratio <= hi, ratio, f"in [{lo:g}, {hi:g}]",
                            f"weighted residual {ratio:.3g} of the instrument's 1 sigma (collar rms "
                            f"{fit.collar_rms_mm:.3g} mm, direction rms {fit.direction_rms_deg:.3g} deg)"))
    if rules[1].passed and math.isfinite(ratio):
        held, how = _holdout_ratio(boom, meas, basis, weights, settings.folds, max_iters, max_condition)
        factor = held / ratio if ratio > 0 else math.inf
        rules.append(RuleResult("holdout", factor <= settings.holdout_factor, factor,
                                f"<= {settings.holdout_factor:g} x the training residual",
                                f"{how}: held-out weighted residual {held:.3g} against {ratio:.3g} in training"))
    else:
        rules.append(RuleResult("holdout", False, math.inf, f"<= {settings.holdout_factor:g} x the training residual",
                                "not run: too few poses or a non-finite fit"))
    residual = weighted_residuals(boom, fit.twists, meas, weights)
    warnings = []
    groups = duplicate_rows(meas)
    if groups:
        text = f"{sum(len(g) for g in groups)} rows repeat a joint vector: " + "; ".join(
            "rows " + ", ".join(str(i + 1) for i in g) for g in groups[:5])
        if settings.duplicates == "refuse":
            rules.append(RuleResult("duplicates", False, float(len(groups)), "none (calibration.gate.duplicates)",
                                    text))
        else:
            warnings.append(text)
    return GateReport(rules, likely_causes(meas, rules, residual), warnings)


def rejected_path(model_path):
    """Where a rejected fit's report goes: beside the model, never over it."""
    return model_path.with_name(model_path.stem + ".rejected.yaml")


def write_rejected(model_path, report: GateReport, summary: dict) -> None:
    doc = {"rejected": True, "model_file_kept": str(model_path), **summary, **report.as_dict()}
    head = ("# A calibration fit that failed the quality gate (pipeline.calibration.quality); the model file\n"
            "# named below was left as it was. docs/calibration.md, 'The quality gate', says what each rule means.\n")
    write_text(head + yaml.safe_dump(doc, sort_keys=False), rejected_path(model_path))


def rejection_message(source: str, report: GateReport, report_path) -> str:
    failed = "; ".join(f"{r.name}: {r.detail} (needs {r.limit})" for r in report.rules if not r.passed)
    causes = (" Likely cause: " + "; ".join(report.causes) + ".") if report.causes else ""
    return (f"{source}: calibration fit rejected, the model file was not changed. {failed}.{causes} "
            f"Report: {report_path}")
