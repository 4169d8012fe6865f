"""Imports point one way: down the layer order of docs/design.md ("Layers"), with no module cycle, and
no study stage reaches the product side (drill plans, motion, solve)."""

import ast
import functools
import importlib.metadata
import re
import sys
import tomllib

import import_graph as g
import pytest

MODULES = g.sources()


def product_modules(modules: set[str]) -> list[str]:
    def product(m: str) -> bool:
        return g.layer(m) in g.PRODUCT_PACKAGES or (g.layer(m) == "stages" and m.split(".")[-1] in g.PRODUCT_STAGES)

    return sorted(filter(product, modules))


def test_the_order_here_is_the_order_in_the_design_notes():
    text = (g.ROOT / "docs/design.md").read_text()
    stated = re.search(r"^ {4}(core <[^`]*?stages)$", text, re.M | re.S).group(1)
    assert [name.strip() for name in stated.split("<")] == g.LAYERS


def test_every_import_points_down_the_layer_order():
    bad = g.violations(MODULES)
    assert not bad, "imports against the layer order (docs/design.md, Layers):\n" + "\n".join(bad)


def test_no_module_import_cycle():
    assert g.cycles(g.graph(MODULES)) == []


def test_every_stage_is_a_study_or_a_product_stage():
    stages = {m.split(".")[-1] for m in MODULES if g.layer(m) == "stages"}
    assert stages == g.STUDY_STAGES | g.PRODUCT_STAGES
    assert not g.STUDY_STAGES & g.PRODUCT_STAGES


@pytest.mark.parametrize("stage", sorted(g.STUDY_STAGES))
def test_no_study_stage_imports_the_product_side(stage):
    reached = product_modules(g.closure(f"pipeline.{stage}", MODULES))
    assert not reached, f"study stage {stage} reaches the product side: {reached}"


def test_the_product_side_is_really_there():
    """The closure test above would pass vacuously if the product modules were not seen at all."""
    assert {"pipeline.plans.model", "pipeline.plans.iredes", "pipeline.plans.demo_face"} <= set(
        product_modules(g.closure("pipeline.solve", MODULES) | g.closure("pipeline.demo_face", MODULES)))


# --- the checker itself, on planted sources ---------------------------------------------------

PLANTED = {
    "pipeline": "",
    "pipeline.core": "",
    "pipeline.core.errors": "",
    "pipeline.geometry": "",
    "pipeline.geometry.kinematics": "from pipeline.core.errors import X\n",
    "pipeline.learning": "",
    "pipeline.learning.models": "import pipeline.geometry.kinematics\n",
    "pipeline.plans": "",
    "pipeline.plans.model": "",
    "pipeline.tracking": "",
    "pipeline.tracking.runs": "",
}


def planted(**extra: str) -> dict[str, str]:
    return {**PLANTED, **{k.replace("__", "."): v for k, v in extra.items()}}


def test_the_checker_passes_a_clean_graph():
    assert g.violations(planted()) == [] and g.cycles(g.graph(planted())) == []


@pytest.mark.parametrize(("module", "source", "message"), [
    ("pipeline.geometry.kinematics", "from pipeline.learning.models import IKNet\n",
     "points up (geometry -> learning)"),
    ("pipeline.geometry.kinematics", "def f():\n    from pipeline.learning import models\n",
     "lazy import of pipeline.learning.models points up"),
    ("pipeline.core.errors", "import pipeline.tracking.runs as r\n", "points up (core -> tracking)"),
    ("pipeline.learning.models", "from pipeline import train\n", "points up (learning -> stages)"),
    ("pipeline.learning.models", "from ..plans import model\n", "pipeline.plans.model points up"),
    ("pipeline.geometry.kinematics", "import pipeline.robots.arm\n", "in no layer"),
])
def test_the_checker_catches_a_planted_import_against_the_order(module, source, message):
    modules = planted(**{module.replace(".", "__"): source})
    modules.setdefault("pipeline.train", "")
    modules.setdefault("pipeline.robots.arm", "")
    assert any(message in v for v in g.violations(modules)), g.violations(modules)


def test_the_checker_catches_a_stage_importing_a_stage_and_an_unknown_package():
    modules = planted(pipeline__train="", pipeline__export="from pipeline import train\n",
                      pipeline__robots="", pipeline__robots__arm="")
    bad = g.violations(modules)
    assert any("pipeline.export:1: import of pipeline.train points sideways" in v for v in bad), bad
    assert any("package 'robots' is not in the layer order" in v for v in bad), bad


def test_the_checker_catches_a_cycle_through_a_lazy_import():
    modules = planted(pipeline__plans__model="def f():\n    from pipeline.plans.iredes import g\n",
                      pipeline__plans__iredes="from pipeline.plans.model import DrillPlan\n")
    assert g.violations(modules) == []  # one package: not a layer violation, but a cycle
    assert g.cycles(g.graph(modules)) == [["pipeline.plans.iredes", "pipeline.plans.model"]]


def test_the_closure_reaches_the_product_side_through_a_lazy_import():
    modules = planted(pipeline__generate="def f():\n    from pipeline.tracking.runs import x\n",
                      pipeline__tracking__runs="def g():\n    import pipeline.plans.model\n")
    assert product_modules(g.closure("pipeline.generate", modules)) == ["pipeline.plans", "pipeline.plans.model"]


# --- declared dependencies ----------------------------------------------------------------------


def third_party(paths) -> set[str]:
    """Top-level names of the non-standard-library, non-project modules these files import."""
    names = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    local = {p.stem for p in (g.ROOT / "tests").glob("*.py")}
    return {n for n in names if n not in sys.stdlib_module_names and n != g.PACKAGE and n not in local}


def declared(*extras: str) -> set[str]:
    project = tomllib.loads((g.ROOT / "pyproject.toml").read_text())["project"]
    reqs = project["dependencies"] + [r for e in extras for r in project["optional-dependencies"][e]]
    return {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower().replace("_", "-") for r in reqs}


@functools.cache
def _owners() -> dict[str, list[str]]:
    """Top-level module -> distributions: one scan of the installed packages, not one per module (each scan
    took most of a second: the two parametrisations 19.8 s and 8.0 s before)."""
    return importlib.metadata.packages_distributions()


def distributions(module: str) -> set[str]:
    return {d.lower().replace("_", "-") for d in _owners().get(module, [module])}


@pytest.mark.parametrize(("folder", "extras"), [("pipeline", ("onnx",)), ("tests", ("onnx", "dev"))])
def test_every_imported_package_is_declared(folder, extras):
    deps = declared(*extras)
    missing = sorted(m for m in third_party((g.ROOT / folder).rglob("*.py")) if not distributions(m) & deps)
    assert not missing, f"{folder}/ imports {missing}, not declared in pyproject.toml"
