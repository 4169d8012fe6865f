"""Stage ``paper_baselines``: the baseline papers' own experiments, next to their numbers.

    python -m pipeline.paper_baselines

Papers 002 (PSO family on huang9 and jumbo8), 003 (GA on rescue6) and 001 (RBF on jumbo8); see
:mod:`pipeline.evaluation.paper_experiments`. Writes ``paths.data/benchmark/papers/{pso,
pso_population,ga,rbf}.csv`` and ``papers.md``, and logs them to MLflow (run ``paper_baselines``).
"""

from __future__ import annotations

import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.assembly.build import load_boom
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import InputError
from pipeline.core.io import write_csv, write_text
from pipeline.core.settings import parse
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.hole_sets import read_hole_poses
from pipeline.data.holes import joint_box
from pipeline.data.tables import COLLAR_COLUMNS, TOE_COLUMNS, collar_toe_poses, read_table
from pipeline.evaluation.markdown import markdown_table
from pipeline.evaluation.paper_experiments import (
    PapersSettings,
    ga_experiments,
    paper_metrics,
    pso_experiments,
    rbf_experiment,
)
from pipeline.solvers import check_entry
from pipeline.tracking.runs import TrackingSettings, stage_run


def run(cfg: DictConfig) -> dict:
    papers, tracking = cfg.solver_benchmark.papers, TrackingSettings.from_config(cfg.tracking)
    # sizes before any work
    parse(PapersSettings, OmegaConf.to_container(papers, resolve=True), "solver_benchmark.papers")
    rbf_specs = {m: OmegaConf.to_container(cfg.solver_benchmark.solvers[m], resolve=True) for m in papers.rbf.methods}
    for m, spec in rbf_specs.items():  # the entries' sizes, before any input is read
        check_entry(m, spec)
    data = project_path(cfg.paths.data)
    out = data / "benchmark" / "papers"
    # inputs first: the swarms take minutes, a missing hole set must not wait for them
    holes = {k: read_hole_poses(data / "holes", f"test_group_{k}.parquet") for k in papers.rbf.groups}
    poses = torch.cat([pose for _, pose in holes.values()]).double()
    boom = load_boom(cfg.boom)
    face = blast_holes(data / "plans" / "demo_face.csv", boom.preview_depth)
    box = cfg.holes.sup.get("box")
    box = joint_box(boom, None if box is None else as_dict(box))
    with stage_run(tracking, "paper_baselines", {"stage": "paper_baselines"}) as mlrun:
        mlrun.log_params({"papers": OmegaConf.to_container(papers, resolve=True)})
        tables = {}
        tables["pso"], tables["pso_population"] = pso_experiments(papers.pso)
        tables["ga"] = ga_experiments(papers.ga)
        tables["rbf"] = rbf_experiment(rbf_specs, boom, poses, face, box)
        for name, df in tables.items():
            write_csv(df, out / f"{name}.csv")
            mlrun.log_table(df, f"tables/{name}.json")
        write_text("".join(f"## {name}\n\n{markdown_table(df)}\n" for name, df in tables.items()), out / "papers.md")
        mlrun.log_metrics(paper_metrics(tables))
        mlrun.log_artifact(out / "papers.md")
    return tables


def blast_holes(path, depth: float) -> torch.Tensor:
    """Paper 001 verifies on a 63-hole face: the demo face's holes less its relief holes (large,
    uncharged, reamed with another bit), 63 with the default layout. Read as a plain hole table:
    a study stage does not import the drill-plan side (pipeline.plans)."""
    holes = read_table(path, [*COLLAR_COLUMNS, *TOE_COLUMNS])
    if "hole_type" not in holes.columns:
        raise InputError(f"{path}: missing column 'hole_type'; found {list(holes.columns)}")
    keep = holes[holes["hole_type"] != "relief"]
    return collar_toe_poses(keep[COLLAR_COLUMNS].to_numpy(), keep[TOE_COLUMNS].to_numpy(), depth)


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads="threads")


if __name__ == "__main__":
    main()
