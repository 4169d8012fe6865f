"""Stage ``report``: a Markdown report of the study next to paper 000's numbers.

    python -m pipeline.report

Writes ``paths.data/report/README.md`` and its figures, and ``seeds.csv`` (``method, seed, kept, mean_mm,
collision_rate_pct``: each seed's network on the test groups), and logs them to MLflow.
"""

from __future__ import annotations

import json
import logging

import pandas as pd
from omegaconf import DictConfig

from pipeline.core.config import project_path
from pipeline.core.errors import InputError
from pipeline.core.io import copy_file, write_csv, write_text
from pipeline.core.stage import run_stage, stage_main
from pipeline.evaluation.markdown import markdown_rows
from pipeline.evaluation.paper_numbers import PAPER000, PAPER000_CUIKM_GAIN, PAPER000_TABLE3
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)


def _fmt(value, spec: str = ".2f") -> str:
    return "—" if value is None else format(value, spec)


METRIC_HEADER = ["method", "mean hole-seeking error (mm)", "over seeds (mm)", "paper", "median", "p95", "max",
                 "direction error mean (deg)", "collision rate (%)", "over seeds (%)", "paper (%)",
                 "holes with any violation (%)", "solve time / 1 000 holes (ms)"]
SEED_REPORT_COLUMNS = ["method", "seed", "kept", "mean_mm", "collision_rate_pct"]


def _spread(s: dict, key: str, spec: str = ".2f") -> str:
    """``mean ± std (n)`` over the method's seeds, or — for a method trained once."""
    if s.get("seeds", 0) < 2:
        return "—"
    return f"{format(s[key + '_seed_mean'], spec)} ± {format(s[key + '_seed_std'], spec)} ({s['seeds']})"


LOOP_HEADER = ["round", "holes within tolerance", "collar deviation mean / p95 / max (mm)", "toe deviation mean (mm)",
               "direction error mean (deg)"]


def loop_lines(loop: dict[str, dict]) -> list[str]:
    """The as-drilled loop's table: the round drilled by a boom at the field level, planned on the nominal model
    (before) and on the model calibrated from its measured poses (after), each read back from its log."""
    rows = []
    def mm(q: dict, k: str) -> str:
        return f"{1000 * q[k]:.2f}" if q.get(k) is not None else "—"

    for name, q in loop.items():
        rows.append([name, f"{q['within']} of {q['holes_planned']}",
                     f"{mm(q, 'collar_dev_m_mean')} / {mm(q, 'collar_dev_m_p95')} / {mm(q, 'collar_dev_m_max')}",
                     mm(q, "toe_dev_m_mean"), _fmt(q.get("direction_err_deg_mean"), ".3f")])
    return ["", "## The as-drilled loop (the demo round, a boom at the field level, calibrated from 60 measured poses)",
            "", markdown_rows(LOOP_HEADER, rows).rstrip("\n")]


def render(metrics: dict, collisions: pd.DataFrame, figures: list[str], loop: dict[str, dict] | None = None) -> str:
    lines = [
        "# IK study report",
        "",
        "Measured on the five test groups (1 000 holes each unless configured otherwise), next to Wu et al. 2024.",
        "The first figures are the network the other stages use (the seed with the best held-out error); "
        "\"over seeds\" gives the mean ± std over every seed trained (their count in brackets).",
        "",
    ]
    rows = []
    for m in sorted(metrics, key=lambda m: (list(PAPER000).index(m) if m in PAPER000 else 0.5, m)):
        s, paper = metrics[m], PAPER000.get(m, {})
        rows.append([m.upper(), f"{s['hole_mm_mean']:.2f}", _spread(s, "mean_mm"),
                     _fmt(paper.get("hole_mm_mean"), ".1f"),
                     f"{s['hole_mm_median']:.2f}", f"{s['hole_mm_p95']:.2f}", f"{s['hole_mm_max']:.1f}",
                     f"{s['direction_deg_mean']:.3f}", f"{100 * s['collision_rate_paper']:.2f}",
                     _spread(s, "collision_rate_pct"), _fmt(paper.get("collision_rate_pct")),
                     f"{100 * s['any_violation_share']:.2f}", f"{s['solve_ms_per_1000']:.2f}"])
    lines.append(markdown_rows(METRIC_HEADER, rows).rstrip("\n"))
    if "sikm" in metrics and "cuikm" in metrics:  # paper 000's headline: CUIKM's error reduction over SIKM
        gain = 1 - metrics["cuikm"]["hole_mm_mean"] / metrics["sikm"]["hole_mm_mean"]
        lines += ["", f"CUIKM's mean hole-seeking error is {100 * gain:.2f} % below SIKM's "
                      f"(Wu et al. 2024: {100 * PAPER000_CUIKM_GAIN:.2f} %)."]
    lines += ["", "## Collisions per test group (Wu et al. 2024 Table 3 layout; the paper's counts in brackets)", ""]
    rows = []
    for _, row in collisions.iterrows():
        paper = PAPER000_TABLE3.get(row["method"])
        g = int(row["group"])
        ref = paper[g - 1] if paper and 1 <= g <= len(paper) else None
        cells = [f"{int(row[k])} ({ref[i]})" if ref else f"{int(row[k])}" for i, k in enumerate(SAFETY_KINDS)]
        rows.append([g, row["method"].upper(), *cells])
    lines.append(markdown_rows(["group", "method", *SAFETY_KINDS], rows).rstrip("\n"))
    if loop:
        lines += loop_lines(loop)
    lines += ["", "## Figures", ""] + [f"![{f}](figures/{f})" for f in figures] + [""]
    return "\n".join(lines)


def run(cfg: DictConfig) -> str:
    tracking = TrackingSettings.from_config(cfg.tracking)
    data = project_path(cfg.paths.data)
    ev, out = data / "eval", data / "report"
    for needed in (ev / "metrics.json", ev / "collisions.csv"):
        if not needed.is_file():
            raise InputError(f"{needed}: missing; run python -m pipeline.evaluate (or dvc repro evaluate) first")
    metrics = json.loads((ev / "metrics.json").read_text())
    collisions = pd.read_csv(ev / "collisions.csv")
    seeds = pd.read_csv(ev / "seeds.csv") if (ev / "seeds.csv").is_file() else pd.DataFrame(columns=SEED_REPORT_COLUMNS)
    # the evaluation's figures, and paper 000's Fig. 5 (the hole sets' collars) from generate
    sources = {p.name: p for p in [*sorted((ev / "figures").glob("*.png")), data / "figures" / "collar_clouds.png"]
               if p.is_file()}
    figures = list(sources)
    with stage_run(tracking, "report", {"stage": "report"}) as mlrun:
        for name, src in sources.items():
            copy_file(src, out / "figures" / name)
        # the as-drilled loop's quality summaries (dvc.yaml's loop_before / loop_after), when the study ran it
        loop = {name: json.loads(path.read_text()) for name, path in
                (("planned on the nominal model", data / "loop" / "before" / "demo_face_quality.json"),
                 ("planned on the calibrated model", data / "loop" / "after" / "demo_face_quality.json"))
                if path.is_file()}
        text = render(metrics, collisions, figures, loop)
        write_text(text, out / "README.md")
        write_csv(seeds[SEED_REPORT_COLUMNS], out / "seeds.csv")  # one row per method and seed: the error bars' data
        mlrun.log_artifact(out / "seeds.csv", "report")
        mlrun.log_text(text, "report/README.md")
        mlrun.log_artifact(out / "figures", "report/figures")
    log.info("report written to %s", out / "README.md")
    return text


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)  # torch's default threads


if __name__ == "__main__":
    main()
