"""The house rules a maintainer relies on, checked on the source: layering without import circles
(imports inside functions and ``mmdopt.bench`` counted), no private name imported across
modules, no hidden module state, short functions and modules, small config classes, one Ruiz
scaling, plan-method names compared only in the registry, no diary in the docs."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("solvers", "frenet", "mmdopt")


def _modules(package: str) -> dict[str, Path]:
    out = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path) -> set[str]:
    """Modules of the repository that ``name`` imports at module level (not inside functions,
    not under ``TYPE_CHECKING``)."""
    tree = ast.parse(path.read_text())
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        for sub in ast.walk(node) if not isinstance(node, ast.FunctionDef | ast.ClassDef) else ():
            if isinstance(sub, ast.Import):
                found |= {a.name for a in sub.names}
            elif isinstance(sub, ast.ImportFrom):
                base = sub.module or ""
                if sub.level:
                    up = pkg.split(".")[: len(pkg.split(".")) - (sub.level - 1)]
                    base = ".".join([*up, base] if base else up)
                found.add(base)
                found |= {f"{base}.{a.name}" for a in sub.names}
    return found


def _all_imports(name: str, path: Path) -> list[tuple[str, str | None]]:
    """Every import of ``name``, at any depth (inside functions too; not under
    ``TYPE_CHECKING``): ``(module, imported name or None)`` pairs, relative imports resolved."""
    tree = ast.parse(path.read_text())
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip |= {id(n) for n in ast.walk(node)}
    out: list[tuple[str, str | None]] = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out += [(a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                base = ".".join([*up, base] if base else up)
            out += [(base, a.name) for a in node.names]
    return out


def _full_graph() -> dict[str, set[str]]:
    """The module graph of the three packages, ``mmdopt.bench`` included, every import counted
    (a package's ``__init__`` re-exports its modules: edges from a module up into its own
    package's ``__init__`` are dropped, as in the module-level test)."""
    mods: dict[str, Path] = {}
    for package in PACKAGES:
        mods |= _modules(package)
    graph: dict[str, set[str]] = {}
    for m, p in mods.items():
        edges = set()
        for base, name in _all_imports(m, p):
            target = f"{base}.{name}" if name and f"{base}.{name}" in mods else base
            if target in mods and target != m and not m.startswith(target + "."):
                edges.add(target)
        graph[m] = edges
    return graph


def test_no_import_circle_counting_imports_inside_functions():
    _check_acyclic(_full_graph())


def test_no_private_name_imported_across_modules():
    """``from x import _name`` across modules hides a dependency on what ``x`` may change; a
    name another module needs is public (``frenet`` imports no private name of ``solvers``)."""
    bad = []
    for package in PACKAGES:
        for m, p in _modules(package).items():
            for base, name in _all_imports(m, p):
                if base.split(".")[0] not in PACKAGES or not name:
                    continue
                if name.startswith("_") and not name.startswith("__"):
                    bad.append(f"{m} imports {base}.{name}")
    assert not bad, bad


def test_no_module_of_the_method_over_1000_lines():
    long = []
    for m, p in _modules("mmdopt").items():
        if m.startswith("mmdopt.bench"):
            continue
        n = len(p.read_text().splitlines())
        if n > 1000:
            long.append(f"{m}: {n} lines")
    assert not long, long


def test_one_ruiz_scaling_in_solvers():
    defs = []
    for m, p in _modules("solvers").items():
        for fn in _functions(ast.parse(p.read_text())):
            if "ruiz" in fn.name.lower():
                defs.append(f"{m}.{fn.name}")
    assert len(defs) == 1, defs


def test_plan_method_names_are_compared_only_in_the_registry():
    """A method is a record of :mod:`mmdopt.methods`: code reads its fields, never tests its
    name (``method == "mmd"``, ``m in ("saa", ...)``), so a new method is one record."""
    import mmdopt.methods

    names = set(mmdopt.methods.PLAN_METHODS)
    bad = []
    for package in PACKAGES:
        for m, p in _modules(package).items():
            if m == "mmdopt.methods":
                continue
            for node in ast.walk(ast.parse(p.read_text())):
                if not isinstance(node, ast.Compare):
                    continue
                for side in (node.left, *node.comparators):
                    consts = [side] if isinstance(side, ast.Constant) else []
                    if isinstance(side, ast.Tuple | ast.List | ast.Set):
                        consts = [e for e in side.elts if isinstance(e, ast.Constant)]
                    if any(isinstance(c.value, str) and c.value in names for c in consts):
                        bad.append(f"{m}:{node.lineno}: {ast.unparse(node)[:80]}")
    assert not bad, bad


def test_no_import_circle_within_a_package():
    for package in PACKAGES:
        mods = _modules(package)
        graph = {m: {i for i in _imports(m, p) if i in mods and i != m} for m, p in mods.items()}
        # a package's __init__ re-exports its modules: edges into it from its own modules are the
        # only ones allowed to point up, and none may point back down into a cycle
        for m in graph:
            graph[m] = {i for i in graph[m] if not m.startswith(i + ".")}
        _check_acyclic(graph)


def _check_acyclic(graph: dict[str, set[str]]) -> None:
    state: dict[str, int] = {}

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for n in graph[m]:
            if state.get(n) == 1:
                cycle = [*stack[stack.index(n) :], n] if n in stack else [m, n]
                pytest.fail(f"import circle: {' -> '.join(cycle)}")
            if n not in state:
                visit(n, [*stack, n])
        state[m] = 2

    for m in graph:
        if m not in state:
            visit(m, [m])


def test_layers_point_one_way():
    order = {"solvers": 0, "frenet": 1, "mmdopt": 2}
    for package in PACKAGES:
        for m, p in _modules(package).items():
            if m.startswith("mmdopt.bench") or m == "mmdopt.__main__":  # the CLI's entry point
                continue
            for i in _imports(m, p):
                top = i.split(".")[0]
                assert not (top in order and order[top] > order[package]), f"{m} imports {i}"
                assert not i.startswith("mmdopt.bench"), f"{m} imports {i}"


_MUTABLE = (ast.Dict, ast.List, ast.Set, ast.DictComp, ast.ListComp, ast.SetComp)


def test_no_mutable_module_state_in_the_method():
    """Module-level dicts, lists and sets in the method's modules (outside ``mmdopt.bench``) are
    read-only (MappingProxyType, tuples); the one exception is the documented planner cache."""
    allowed = {("mmdopt.planner", "PLANNERS"), ("mmdopt.methods", "REGISTRY")}
    for m, p in _modules("mmdopt").items():
        if m.startswith("mmdopt.bench"):
            continue
        for node in ast.parse(p.read_text()).body:
            targets, value = [], None
            if isinstance(node, ast.Assign):
                targets, value = node.targets, node.value
            elif isinstance(node, ast.AnnAssign) and node.value is not None:
                targets, value = [node.target], node.value
            for t in targets:
                name = ast.unparse(t)
                if name == "__all__" or (m, name) in allowed:
                    continue
                mutable = isinstance(value, _MUTABLE) or (
                    isinstance(value, ast.Call)
                    and ast.unparse(value.func) in ("dict", "list", "set")
                )
                assert not mutable, f"{m}.{name} is a mutable module-level container"


def _functions(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield node


def test_no_function_over_120_lines():
    long = []
    for package in PACKAGES:
        for m, p in _modules(package).items():
            for fn in _functions(ast.parse(p.read_text())):
                n = fn.end_lineno - fn.lineno + 1
                if n > 120:
                    long.append(f"{m}.{fn.name}: {n} lines")
    assert not long, long


def test_no_config_class_over_20_fields():
    big = []
    for package in PACKAGES:
        for m, p in _modules(package).items():
            for node in ast.walk(ast.parse(p.read_text())):
                if isinstance(node, ast.ClassDef) and (
                    "Config" in node.name or "Settings" in node.name
                ):
                    n = sum(isinstance(s, ast.AnnAssign) for s in node.body)
                    if n > 20:
                        big.append(f"{m}.{node.name}: {n} fields")
    assert not big, big


#: a development diary's wording (work sessions and issue numbers, an internal spec's sections,
#: the machine a change was made on), spelled in parts so that no file holds the phrases
DIARY = re.compile(
    "|".join(
        (
            r"\b[Ss]ess" + r"ion \d",
            r"\bissues? " + r"\d",
            "SP" + "EC §",
            r"\bthis " + r"VM\b",
        )
    )
)


def test_no_diary_in_code_docs_or_tests():
    hits = []
    roots = [ROOT / d for d in (*PACKAGES, "docs", "tests", "benchmarks")] + [ROOT / "README.md"]
    for root in roots:
        files = [root] if root.is_file() else root.rglob("*")
        for f in files:
            if f.suffix not in (".py", ".md"):
                continue
            for i, line in enumerate(f.read_text(errors="replace").splitlines(), 1):
                if DIARY.search(line):
                    hits.append(f"{f.relative_to(ROOT)}:{i}: {line.strip()[:80]}")
    assert not hits, hits[:20]
