"""Each DVC stage's code deps are exactly the files of its import closure: every file it may run is a
dep (so `dvc repro` cannot call it up to date after its code changed), and every code dep is a file it
runs (so editing a module it never runs, a drill-plan reader say, does not retrain the study).

Settings reach a stage as params (params.yaml, the composition of conf/), never as files read behind
DVC's back: no module below the composition root (the stages, ``pipeline/assembly/``,
``pipeline/core/config.py``) reads ``conf/``; a conf file a stage's cmd names (``rig=twin``) is a dep;
and every stage that times motion lists ``motion`` in its params."""

import ast
import re

import import_graph as g
import pytest
import yaml

MODULES = g.sources()
DATA = "${paths.data}/"


PIPELINES = ["dvc.yaml", "sweeps/dvc.yaml"]  # the study and the product side; the sweeps (their own pipeline)


def _lookup(params: dict, dotted: str):
    node = params
    for part in dotted.split("."):
        node = node[part]
    return node


def stages() -> dict[str, dict]:
    """Every pipeline's stages, ``foreach`` expanded (over a mapping written out or over a params value,
    ``${sweeps.jobs}``), and the file names that come from a params value (``${distill.teacher}``: a setting,
    not a path) resolved from params.yaml as DVC resolves them. A stage of sweeps/dvc.yaml is named as DVC
    names it (``sweeps/dvc.yaml:job@mu-1``)."""
    params = yaml.safe_load((g.ROOT / "params.yaml").read_text())
    out = {}
    for pipeline in PIPELINES:
        text = (g.ROOT / pipeline).read_text()
        for key in ("teacher", "name"):
            text = text.replace(f"${{distill.{key}}}", params["distill"][key])
        prefix = "" if pipeline == "dvc.yaml" else f"{pipeline}:"
        for name, stage in yaml.safe_load(text)["stages"].items():
            body = stage.get("do", stage)
            items = stage.get("foreach", {None: None})
            if isinstance(items, str):
                items = _lookup(params, items.removeprefix("${").removesuffix("}"))
            for key, item in items.items():
                resolved = body
                if key is not None:
                    dumped = yaml.safe_dump(body).replace("${key}", str(key))
                    for field, value in (item.items() if isinstance(item, dict) else []):
                        dumped = dumped.replace(f"${{item.{field}}}", str(value))
                    resolved = yaml.safe_load(dumped)
                out[f"{prefix}{name}" if key is None else f"{prefix}{name}@{key}"] = resolved
    return out


STAGES = stages()


CONF = "conf/"


def code_deps(stage: dict) -> list[str]:
    """The stage's own code (its import closure); the checker it runs as a separate process is
    ``scripts/`` (test_execute_depends_on_the_checker_it_runs)."""
    return [d for d in stage["deps"] if not d.startswith((DATA, CONF, "scripts/"))]


def test_execute_depends_on_the_checker_it_runs():
    """pipeline.execute runs scripts/check_round.py (which imports nothing of pipeline): a change to the
    checker must re-run the stage, so DVC hashes the script and its package."""
    from pipeline.execute import CHECKER

    for name, stage in STAGES.items():
        if "python -m pipeline.execute" in stage["cmd"]:
            assert CHECKER in stage["deps"] and "scripts/round_check" in stage["deps"], name
    assert (g.ROOT / CHECKER).is_file() and (g.ROOT / "scripts/round_check/__init__.py").is_file()


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
            # the out itself, a file in an out folder, or a folder of other stages' outs (a sweep's jobs)
            assert any(dep == o or dep.startswith(o + "/") or o.startswith(dep + "/") for o in outs), \
                f"{name}: no stage writes {dep}"


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
    for pipeline in PIPELINES[1:]:
        text = (g.ROOT / pipeline).read_text()
        assert g.rewrite_dvc_code_deps(text, MODULES) == text, pipeline
    text = (g.ROOT / "dvc.yaml").read_text()
    assert g.rewrite_dvc_code_deps(text, MODULES) == text
    coarse = text.replace("      - pipeline/evaluate.py\n", "      - pipeline/evaluate.py\n      - pipeline/plans\n", 1)
    coarse = coarse.replace("\n      - pipeline/evaluation/metrics.py\n", "\n", 1)  # evaluate's, not train's
    assert coarse != text and g.rewrite_dvc_code_deps(coarse, MODULES) == text


# --- settings: params, never conf/ files read below the composition root ---------------------------------

CONF_READERS = {"load_group_file", "CONF_DIR", "config_dir", "compose", "available"}  # core.config's conf/ readers
PATH_CALLS = {"Path", "PurePath", "open", "load", "safe_load", "read_text", "glob", "is_file", "exists"}


def composition_root(module: str) -> bool:
    """Where conf/ may be read: the stages, the assembly (docs/design.md), the config loader itself and the
    stages' one Hydra entry (pipeline.core.stage: ``hydra.main`` on the config folder)."""
    return g.layer(module) in ("stages", "assembly") or module in ("pipeline.core.config", "pipeline.core.stage")


def _conf_text(node) -> bool:
    """A string constant or f-string that is a path into conf/."""
    if isinstance(node, ast.JoinedStr):
        node = node.values[0] if node.values else None
    return isinstance(node, ast.Constant) and isinstance(node.value, str) and (
        node.value == "conf" or node.value.startswith(CONF))


def conf_reads(modules: dict[str, str]) -> list[str]:
    """``module:line: what`` for every read of conf/ below the composition root: a use of one of
    pipeline.core.config's readers (imported, or as an attribute), or a ``conf/`` path built or opened."""
    bad = []
    for module, source in modules.items():
        if composition_root(module):
            continue
        for node in ast.walk(ast.parse(source)):
            line = getattr(node, "lineno", 0)
            if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("core.config"):
                bad += [f"{module}:{line}: imports {a.name}" for a in node.names if a.name in CONF_READERS]
            elif isinstance(node, ast.Attribute) and node.attr in CONF_READERS and isinstance(node.value, ast.Name) \
                    and node.value.id == "config":
                bad.append(f"{module}:{line}: uses config.{node.attr}")
            elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) and (
                    _conf_text(node.left) or _conf_text(node.right)):
                bad.append(f"{module}:{line}: builds a conf/ path")
            elif isinstance(node, ast.Call) and any(_conf_text(a) for a in node.args):
                name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
                if name in PATH_CALLS:
                    bad.append(f"{module}:{line}: {name}() of a conf/ path")
    return bad


CLEAN = {"pipeline": "", "pipeline.core": "", "pipeline.core.config": "CONF_DIR = 1\ndef load_group_file(): pass\n",
         "pipeline.assembly": "", "pipeline.assembly.rig": "from pipeline.core.config import load_group_file\n",
         "pipeline.schedule": "from pipeline.core.config import load_group_file, compose\n",
         "pipeline.motion": "", "pipeline.motion.timing": "def f(src):\n    raise ValueError(f'conf/motion/{src}')\n"}


def test_the_conf_checker_passes_a_clean_tree():
    assert conf_reads(CLEAN) == []


@pytest.mark.parametrize(("source", "message"), [
    ("from pipeline.core.config import load_group_file\n", "pipeline.motion.timing:1: imports load_group_file"),
    ("def f():\n    from pipeline.core.config import CONF_DIR, as_dict\n", "timing:2: imports CONF_DIR"),
    ("from pipeline.core import config\nx = config.load_group_file('motion', 'jumbo8')\n",
     "timing:2: uses config.load_group_file"),
    ("from ..core.config import compose\n", "imports compose"),
    ("from pathlib import Path\nROOT = Path('.')\np = ROOT / 'conf' / 'motion'\n", "timing:3: builds a conf/ path"),
    ("import yaml\ndef f(n):\n    return yaml.safe_load(open(f'conf/motion/{n}.yaml'))\n",
     "timing:3: open() of a conf/ path"),
    ("from omegaconf import OmegaConf\nx = OmegaConf.load('conf/motion/jumbo8.yaml')\n",
     "timing:2: load() of a conf/ path"),
])
def test_the_conf_checker_catches_a_planted_read(source, message):
    bad = conf_reads({**CLEAN, "pipeline.motion.timing": source})
    assert any(message in b for b in bad), bad


def test_nothing_below_the_composition_root_reads_conf():
    bad = conf_reads(MODULES)
    assert not bad, "conf/ read below the composition root (settings must come in as nodes or objects):\n" + \
        "\n".join(bad)


def named_conf_files(cmd: str) -> set[str]:
    """The conf files a stage's cmd selects by name (``rig=twin``: conf/rig/twin.yaml), which the stage
    then reads itself (params.yaml composes the defaults only)."""
    return {f"{CONF}{k}/{v}.yaml" for k, v in re.findall(r"(?<![\w.+])(\w+)=(\w+)", cmd)
            if (g.ROOT / CONF / k / f"{v}.yaml").is_file()}


def test_the_named_conf_reader_sees_rig_twin():
    assert named_conf_files("python -m pipeline.x ${app} rig=twin a.rig=trio hydra.run.dir=logs") == \
        {"conf/rig/twin.yaml"}


@pytest.mark.parametrize("name", sorted(STAGES))
def test_every_conf_file_a_stage_reads_is_a_dep_and_no_other(name):
    deps = {d for d in STAGES[name]["deps"] if d.startswith(CONF)}
    assert deps == named_conf_files(STAGES[name]["cmd"]), name
    assert all((g.ROOT / d).is_file() for d in deps), name


def params_of(stage: dict) -> set[str]:
    return {p for p in stage.get("params", []) if isinstance(p, str)}


@pytest.mark.parametrize("name", sorted(STAGES))
def test_every_stage_that_times_motion_lists_its_params(name):
    """The motion model is built from the composed ``motion`` node; a stage whose code can time a move
    must list it, or `dvc status` calls it up to date after conf/motion changed."""
    timed = "pipeline/motion/timing.py" in closure_files(STAGES[name])
    assert ("motion" in params_of(STAGES[name])) == timed, (name, timed)


@pytest.mark.parametrize("name", ["schedule", "move_benchmark", "solve"])
def test_the_stages_that_place_a_rig_list_the_boom_models(name):
    assert {"boom", "boom_model", "boom_models"} <= params_of(STAGES[name])


def test_the_motion_check_is_not_vacuous():
    assert "pipeline/motion/timing.py" in closure_files(STAGES["schedule"])
    assert "pipeline/motion/timing.py" in closure_files(STAGES["move_benchmark"])
    assert "pipeline/motion/timing.py" not in closure_files(STAGES["train@cuikm"])
