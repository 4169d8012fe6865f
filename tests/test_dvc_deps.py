"""Each DVC stage depends on every module its command imports, so `dvc repro` cannot call a stage
up to date after code it runs has changed."""

import ast
import re
from pathlib import Path

import pytest
import yaml

from pipeline.core.config import PROJECT_ROOT


def module_file(name: str) -> Path | None:
    """The file of module ``pipeline.a.b`` (a module or a package), or None outside the project."""
    if not name.startswith("pipeline"):
        return None
    base = PROJECT_ROOT / Path(*name.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def imported_modules(path: Path) -> set[str]:
    """Every ``pipeline`` module a file imports, at top level or inside functions."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)  # `from pkg import module`
    return {n for n in names if module_file(n) is not None}


def closure(module: str) -> set[Path]:
    """The files Python runs to import ``module``: its own, its imports', and every parent package's."""
    todo, seen = [module], set()
    files: set[Path] = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        parts = name.split(".")
        for i in range(1, len(parts)):  # importing a.b.c runs a/__init__ and a/b/__init__
            todo.append(".".join(parts[:i]))
        path = module_file(name)
        files.add(path)
        todo.extend(imported_modules(path))
    return files


def stages() -> dict[str, dict]:
    spec = yaml.safe_load((PROJECT_ROOT / "dvc.yaml").read_text())["stages"]
    out = {}
    for name, stage in spec.items():
        body = stage.get("do", stage)
        keys = stage.get("foreach", {None: None})
        for key in keys:
            out[name if key is None else f"{name}@{key}"] = body
    return out


def covered(path: Path, deps: list[str]) -> bool:
    rel = path.relative_to(PROJECT_ROOT)
    return any(rel == Path(d) or Path(d) in rel.parents for d in deps)


STAGES = stages()


def test_every_stage_runs_a_pipeline_module():
    for name, stage in STAGES.items():
        assert re.search(r"python -m (pipeline\.\w+)", stage["cmd"]), name


@pytest.mark.parametrize("name", sorted(STAGES))
def test_stage_deps_cover_its_import_closure(name):
    stage = STAGES[name]
    modules = re.findall(r"python -m (pipeline\.\w+)", stage["cmd"])  # a stage may run several
    deps = [d for d in stage["deps"] if d.startswith("pipeline")]  # data deps are ${paths.data}/...
    files = set().union(*(closure(m) for m in modules))
    missing = sorted(str(p.relative_to(PROJECT_ROOT)) for p in files if not covered(p, deps))
    assert not missing, f"dvc.yaml stage {name!r} imports {missing} but does not depend on them"


def test_the_checker_sees_lazy_imports():
    """train imports the plots inside a function; a checker that missed it would pass vacuously."""
    assert PROJECT_ROOT / "pipeline/evaluation/plots.py" in closure("pipeline.train")
    assert not covered(PROJECT_ROOT / "pipeline/solvers/nm.py", ["pipeline/train.py", "pipeline/core"])
