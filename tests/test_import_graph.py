"""No import cycles between the modules of hr_addon: a static walk (ast) over every module's
imports, including those inside functions (a lazy import hides a cycle, it does not remove it).

The Blender layer (hr_addon.blender, __main__) must be acyclic. Two cycles in core are known
debt, listed with where they are being removed; any other cycle in the package fails.
"""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "hr_addon"


def _modules():
    """name -> (path, package parts the module's relative imports start from)"""
    mods = {}
    for p in PACKAGE.rglob("*.py"):
        parts = list(p.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
            mods[".".join(parts)] = (p, parts)
        else:
            mods[".".join(parts)] = (p, parts[:-1])
    return mods


def import_graph():
    """module -> set of hr_addon modules it imports (a name imported from a package counts as the
    submodule when there is one, else the package)."""
    mods = _modules()
    graph = {}
    for name, (path, pkg) in mods.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = ".".join(pkg[: len(pkg) - node.level + 1] + ([node.module] if node.module else []))
                else:
                    base = node.module or ""
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    deps.add(sub if sub in mods else base)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
        graph[name] = {d for d in deps if d in mods and d != name}
    return graph


def cycles(graph):
    """The strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.add(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(comp)
    return out


def test_the_cycle_finder_finds_a_cycle_and_nothing_else():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(g) == [{"a", "b", "c"}]


def test_the_graph_sees_lazy_and_package_imports():
    g = import_graph()
    assert "hr_addon.blender.state" in g["hr_addon.blender.bake"]  # from .state import STATE
    assert "hr_addon.blender.cli" in g["hr_addon.__main__"]  # inside a function
    assert "hr_addon.blender.live" in g["hr_addon.blender"]  # from . import live (in register)


def test_no_module_of_the_package_is_in_an_import_cycle():
    assert cycles(import_graph()) == []
