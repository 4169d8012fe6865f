"""Each DVC stage's code deps are exactly the files of its import closure: every file it may run is a
dep (so `dvc repro` cannot call it up to date after its code changed), and every code dep is a file it
runs (so editing a module it never runs, a drill-plan reader say, does not retrain the study)."""

import re

import import_graph as g
import pytest
import yaml

MODULES = g.sources()
DATA = "${paths.data}/"


def stages() -> dict[str, dict]:
    spec = yaml.safe_load((g.ROOT / "dvc.yaml").read_text())["stages"]
    out = {}
    for name, stage in spec.items():
        body = stage.get("do", stage)
        for key in stage.get("foreach", {None: None}):
            resolved = yaml.safe_load(yaml.safe_dump(body).replace("${key}", str(key))) if key else body
            out[name if key is None else f"{name}@{key}"] = resolved
    return out


STAGES = stages()


def code_deps(stage: dict) -> list[str]:
    return [d for d in stage["deps"] if not d.startswith(DATA)]


def closure_files(stage: dict) -> set[str]:
    modules = re.findall(r"python -m (pipeline\.\w+)", stage["cmd"])  # a stage may run several
    return {str(g.module_file(m, MODULES).relative_to(g.ROOT)) for s in modules for m in g.closure(s, MODULES)}


def product_file(path: str) -> bool:
    parts = path.removeprefix(DATA).split("/")
    if path.startswith(DATA):
        return parts[0] == "plans"  # the drill plans and their solutions
    return (parts[0] == "pipeline" and len(parts) > 2 and parts[1] in g.PRODUCT_PACKAGES) or (
        len(parts) == 2 and parts[1].removesuffix(".py") in g.PRODUCT_STAGES)


def test_every_stage_runs_a_pipeline_module():
    for name, stage in STAGES.items():
        assert re.search(r"python -m (pipeline\.\w+)", stage["cmd"]), name


@pytest.mark.parametrize("name", sorted(STAGES))
def test_every_file_a_stage_runs_is_a_dep(name):
    missing = sorted(closure_files(STAGES[name]) - set(code_deps(STAGES[name])))
    assert not missing, f"dvc.yaml stage {name!r} runs {missing} but does not depend on them"


@pytest.mark.parametrize("name", sorted(STAGES))
def test_every_code_dep_is_a_file_the_stage_runs(name):
    deps = code_deps(STAGES[name])
    folders = [d for d in deps if (g.ROOT / d).is_dir() or not d.endswith(".py")]
    assert not folders, f"dvc.yaml stage {name!r}: code deps must be files, not {folders}"
    extra = sorted(set(deps) - closure_files(STAGES[name]))
    assert not extra, f"dvc.yaml stage {name!r} depends on {extra}, which it never runs"
    assert len(deps) == len(set(deps)), name


def test_every_data_dep_is_written_by_a_stage():
    outs = {o: n for n, s in STAGES.items() for o in s.get("outs", []) + s.get("metrics", []) + s.get("plots", [])}
    for name, stage in STAGES.items():
        for dep in (d for d in stage["deps"] if d.startswith(DATA)):
            assert any(dep == o or dep.startswith(o + "/") for o in outs), f"{name}: no stage writes {dep}"


@pytest.mark.parametrize("name", [n for n in sorted(STAGES) if n.startswith("train@") or n == "evaluate"])
def test_training_and_evaluation_do_not_depend_on_the_product_side(name):
    """Editing a plan reader, the demo face or solve leaves them up to date: DVC hashes only the deps."""
    product = [d for d in STAGES[name]["deps"] if product_file(d)]
    assert not product, f"{name} depends on product-side files {product}"


def test_train_declares_what_it_writes():
    for key in ("sikm", "sikm_best", "uikm", "cuikm"):
        outs = STAGES[f"train@{key}"]["outs"]
        assert {f"{DATA}models/{key}{s}" for s in (".pt", "_history.csv", "_final.json")} <= set(outs), key


def test_the_demo_face_is_the_product_side_s_own_stage():
    assert {f"{DATA}plans/demo_face.csv", f"{DATA}plans/demo_face.xml"} <= set(STAGES["demo_face"]["outs"])
    assert not [o for o in STAGES["generate"]["outs"] if product_file(o)]


def test_the_checker_sees_lazy_imports_and_product_files():
    """train imports the plots inside a function; a checker that missed it would pass vacuously."""
    assert "pipeline/evaluation/plots.py" in closure_files(STAGES["train@cuikm"])
    assert "pipeline/solvers/nm.py" not in closure_files(STAGES["train@cuikm"])
    assert "pipeline/plans/model.py" in closure_files(STAGES["solve"])
    assert product_file("pipeline/plans/model.py") and product_file("pipeline/solve.py")
    assert product_file(f"{DATA}plans/demo_face.csv") and not product_file("pipeline/data/holes.py")
    assert not product_file(f"{DATA}holes") and not product_file("pipeline/train.py")


def test_the_rewriter_restores_the_exact_deps():
    """`python tests/import_graph.py` (run after moving modules) leaves a true dvc.yaml as it is and
    turns directory deps back into the closure's files."""
    text = (g.ROOT / "dvc.yaml").read_text()
    assert g.rewrite_dvc_code_deps(text, MODULES) == text
    coarse = text.replace("      - pipeline/evaluate.py\n", "      - pipeline/evaluate.py\n      - pipeline/plans\n", 1)
    coarse = coarse.replace("\n      - pipeline/evaluation/metrics.py\n", "\n", 1)  # evaluate's, not train's
    assert coarse != text and g.rewrite_dvc_code_deps(coarse, MODULES) == text
