"""The project's imports, walked: one direction between the packages (firmware_port <- twin <- protocol
<- tools), no circle between modules, and no library module that imports a CLI, a paper's module or
a docs generator. Every import counts, also one inside a function (a lazy import is still a
dependency)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("firmware_port", "twin", "protocol", "tools")  # each may import only those before it
# What a library module (anything else under tools/) must not import: the CLIs, the papers'
# reproductions, the docs generators.
TOP_LEVEL = ("tools.cli", "tools.seeds", "tools.docs")


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for package in PACKAGES for p in (ROOT / package).rglob("*.py")}


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The project modules ``name`` imports (``from pkg import sub`` counts as pkg.sub when that is a module)."""
    found = set()
    is_package = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".")[: len(name.split(".")) - node.level + (1 if is_package else 0)]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
        else:
            continue
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    known = set(modules)
    return {name: _imports(name, path, known) for name, path in modules.items()}


def _rank(module: str) -> int:
    return PACKAGES.index(module.split(".")[0])


def test_packages_import_in_one_direction():
    upward = [f"{m} imports {t}" for m, targets in _graph().items() for t in targets if _rank(t) > _rank(m)]
    assert not upward, "\n".join(sorted(upward))


def _is_top_level(module: str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in TOP_LEVEL)


def test_libraries_never_import_a_cli_a_paper_or_a_docs_generator():
    bad = [f"{m} imports {t}" for m, targets in _graph().items() if m.startswith("tools.") and not _is_top_level(m)
           and m != "tools.bench" for t in targets if _is_top_level(t)]
    assert not bad, "\n".join(sorted(bad))


# Who may import a docs generator (tools/docs): another generator, and the command lines (tools/cli, the
# benchmark, ``python -m tools.seeds``), which may write a page; never a library, nor a paper's module.
DOCS = "tools.docs"
DOCS_IMPORTERS = (DOCS, "tools.cli", "tools.bench", "tools.seeds.__main__")


def _within(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def _docs_imports(graph: dict[str, set[str]]) -> list[str]:
    """``m imports t`` for every import of a docs generator by a module that is neither one nor a CLI."""
    return sorted(f"{m} imports {t}" for m, targets in graph.items() if not _within(m, DOCS_IMPORTERS)
                  for t in targets if _within(t, (DOCS,)))


def test_only_generators_and_clis_import_a_docs_generator():
    bad = _docs_imports(_graph())
    assert not bad, "\n".join(bad)


def test_the_docs_rule_flags_a_paper_or_a_library_importing_a_page():
    graph = {"tools.seeds.seed001": {"tools.docs.seeds_page"}, "tools.tuning.evaluate": {"tools.docs"},
             "tools.cli.tune": {"tools.docs.rules_table"}, "tools.docs.optimtable": {"tools.docs.rules_table"},
             "tools.seeds.__main__": {"tools.docs.seeds_page"}, "tools.docsx": {"tools.docs.crossval"}}
    assert _docs_imports(graph) == ["tools.docsx imports tools.docs.crossval",
                                    "tools.seeds.seed001 imports tools.docs.seeds_page",
                                    "tools.tuning.evaluate imports tools.docs"]


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph.get(node, ()):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_no_import_circles():
    cycles = _cycles(_graph())
    assert not cycles, "\n".join(" <-> ".join(c) for c in cycles)


def test_the_walker_sees_lazy_imports_and_circles():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    tree = _imports("twin.result", ROOT / "twin" / "result.py", set(_modules()))
    assert "twin.metrics" in tree  # a module-level import
