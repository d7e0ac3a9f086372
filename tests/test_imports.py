"""The package's import graph has no cycles (every import statement counts, also those inside functions)."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "harness"


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def import_graph() -> dict[str, set[str]]:
    """``module -> harness modules it imports``; ``from harness.x import y`` counts as importing the module
    ``harness.x.y`` when that is a module, else ``harness.x``."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module
                           for a in node.names]
            else:
                continue
            edges |= {t for t in targets if t in modules and t != name}
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_checker_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_harness_has_no_import_cycles():
    graph = import_graph()
    assert cycles(graph) == []


def test_command_modules_do_not_import_the_cli():
    graph = import_graph()
    assert not [m for m, edges in graph.items() if "harness.cli" in edges and m != "harness.__main__"]


def test_the_kernel_cache_follows_the_kernels_sources(tmp_path):
    """numba reuses a kernel's cache when the kernel's own file is unchanged, even when a function it inlines
    from another file has changed: the cache directory is per version of every file that compiles kernels,
    and only of those."""
    import harness

    package = tmp_path / "package"
    (package / "engine").mkdir(parents=True)
    maths, report = package / "engine" / "maths.py", package / "report.py"
    maths.write_text("import numba\n\n\n@numba.njit\ndef f(x):\n    return x + 1\n")
    report.write_text("def table():\n    return 1\n")
    first = harness.kernel_cache_dir(package)
    assert first.parent == package / "__pycache__" / "numba"
    report.write_text("def table():\n    return 2\n")
    assert harness.kernel_cache_dir(package) == first
    maths.write_text("import numba\n\n\n@numba.njit\ndef f(x):\n    return x + 2\n")
    assert harness.kernel_cache_dir(package) != first
