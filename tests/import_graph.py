"""The import graph of ``pipeline/``, read from the source (AST), for the layer and DVC-deps tests.

Every import counts: top level, inside functions (lazy) and ``from pipeline import x``. Functions
take a ``{module: source}`` mapping, so the tests can plant a violation in a small source string
and see the checker catch it.
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "pipeline"

# The layer order (docs/design.md, "Layers"): a module may import only from its own package or a
# lower one. The stages are the modules pipeline/<stage>.py; one stage never imports another.
LAYERS = ["core", "optim", "geometry", "data", "assembly", "learning", "solvers", "evaluation", "calibration",
          "deploy", "plans", "motion", "round", "events", "rig_benchmarks", "tracking", "stages"]
PRODUCT_PACKAGES = {"plans", "motion", "round", "events", "rig_benchmarks"}
STUDY_STAGES = {"generate", "train", "evaluate", "solver_benchmark", "paper_baselines", "report", "derive_box",
                "export", "export_benchmark", "calibrate", "params", "dashboard", "distill", "field_boom",
                "sweep_table"}
PRODUCT_STAGES = {"solve", "demo_face", "move_benchmark", "schedule", "execute", "quality"}


def module_of(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def sources(root: Path = ROOT) -> dict[str, str]:
    """``{module: source}`` of every file under ``pipeline/``."""
    return {module_of(p, root): p.read_text() for p in sorted((root / PACKAGE).rglob("*.py"))}


def is_package(module: str, modules: dict[str, str], root: Path = ROOT) -> bool:
    return (root / Path(*module.split(".")) / "__init__.py").is_file() or any(
        m.startswith(module + ".") for m in modules)


def imports(module: str, source: str, modules: dict[str, str], root: Path = ROOT) -> list[tuple[str, int, bool]]:
    """``(imported module, line, lazy)`` for every ``pipeline`` import of ``module``. ``from a import b``
    names module ``a.b`` where that is a module, else ``a``."""
    # the checks ask the same (module, source, tree) hundreds of times: parse each once
    return list(_imports(module, source, frozenset(modules), root))


@functools.cache
def _imports(module: str, source: str, modules: frozenset[str], root: Path) -> tuple[tuple[str, int, bool], ...]:
    tree = ast.parse(source)
    top = {id(n) for n in tree.body} | {id(n) for s in tree.body if isinstance(s, (ast.If, ast.Try))
                                         for n in ast.walk(s)}
    package = module if is_package(module, modules, root) else module.rpartition(".")[0]
    found = []
    for node in ast.walk(tree):
        lazy = id(node) not in top
        if isinstance(node, ast.Import):
            found += [(a.name, node.lineno, lazy) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from . import x, from ..a import b
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([base] if base else [])])
            for a in node.names:
                sub = f"{base}.{a.name}"
                found.append((sub if sub in modules else base, node.lineno, lazy))
    unique = dict.fromkeys(found)  # `from a import b, c` is one import of a
    return tuple((m, line, lazy) for m, line, lazy in unique if m == PACKAGE or m.startswith(PACKAGE + "."))


def layer(module: str) -> str | None:
    """The layer of a module: its package under ``pipeline``, ``stages`` for ``pipeline/<stage>.py``
    (and the shims beside them), None for the ``pipeline`` package itself and its ``__main__`` (``boom-ik``,
    which imports a stage by the name it is given, none in its source)."""
    parts = module.split(".")
    if len(parts) == 1 or module == f"{PACKAGE}.__main__":
        return None
    if len(parts) == 2 and parts[1] not in LAYERS:
        return "stages"
    return parts[1]


def unit(module: str) -> str:
    """What "its own package" is: the package under pipeline, or the stage itself."""
    parts = module.split(".")
    return parts[1] if layer(module) != "stages" or len(parts) > 2 else f"stage {parts[1]}"


def violations(modules: dict[str, str], root: Path = ROOT) -> list[str]:
    """Every import pointing up or sideways, and every module in no known layer."""
    bad = []
    for module, source in modules.items():
        own = layer(module)
        if own is None:
            continue
        if own not in LAYERS:
            bad.append(f"{module}: package '{own}' is not in the layer order {LAYERS}")
            continue
        for target, line, lazy in imports(module, source, modules, root):
            other = layer(target)
            if other is None or unit(target) == unit(module):
                continue
            kind = "lazy " if lazy else ""
            if other not in LAYERS:
                bad.append(f"{module}:{line}: {kind}import of {target}, in no layer")
            elif LAYERS.index(other) >= LAYERS.index(own):
                way = "sideways" if other == own else "up"
                bad.append(f"{module}:{line}: {kind}import of {target} points {way} ({own} -> {other})")
    return bad


def graph(modules: dict[str, str], root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the modules it imports (lazy ones too), within ``modules``."""
    return {m: {t for t, _, _ in imports(m, s, modules, root) if t in modules and t != m} for m, s in modules.items()}


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def closure(start: str, modules: dict[str, str], root: Path = ROOT) -> set[str]:
    """The modules Python may run for ``start``: its imports (lazy too), theirs, and every parent package."""
    todo, seen = [start], set()
    while todo:
        name = todo.pop()
        if name in seen or name not in modules:
            continue
        seen.add(name)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]  # importing a.b.c runs a and a.b
        todo += [t for t, _, _ in imports(name, modules[name], modules, root)]
    return seen


def module_file(module: str, modules: dict[str, str], root: Path = ROOT) -> Path:
    base = root / Path(*module.split("."))
    return base / "__init__.py" if is_package(module, modules, root) else base.with_suffix(".py")


def rewrite_dvc_code_deps(text: str, modules: dict[str, str], root: Path = ROOT) -> str:
    """``dvc.yaml`` with each stage's code deps (its ``- pipeline/...`` lines) replaced by the files of
    its import closure, in place of the first one; data deps, comments and order kept."""
    spec = yaml.safe_load(text)["stages"]
    lines, out, stage, i = text.split("\n"), [], None, 0
    while i < len(lines):
        line = lines[i]
        if m := re.match(r"^  (\w+):", line):
            stage = m.group(1)
        out.append(line)
        i += 1
        if not (re.match(r"^\s+deps:", line) and stage in spec):
            continue
        body = spec[stage].get("do", spec[stage])
        run = re.findall(r"python -m (pipeline\.\w+)", body["cmd"])
        reached = {m for s in run for m in closure(s, modules, root)}
        files = sorted(str(module_file(m, modules, root).relative_to(root)) for m in reached)
        indent = re.match(r"^(\s+)", lines[i]).group(1)
        block = [f"{indent}- {f}" for f in files]
        while i < len(lines) and lines[i].startswith(indent + "- "):
            if not lines[i].strip().startswith("- pipeline"):
                out.append(lines[i])
            elif block:
                out += block
                block = []
            i += 1
        out += block
    return "\n".join(out)


if __name__ == "__main__":  # python tests/import_graph.py: refresh the pipelines' code deps after a move
    for path in (ROOT / "dvc.yaml", ROOT / "sweeps" / "dvc.yaml"):
        path.write_text(rewrite_dvc_code_deps(path.read_text(), sources()))
