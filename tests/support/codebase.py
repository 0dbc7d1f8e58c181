"""Static checks of the code base's shape: import graph, private names across modules, docstring size.

Used by ``tests/test_codebase.py``; run as ``python -m tests.support.codebase`` to list every finding.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("capture", "segmentation", "tracker", "service")
MAX_DOCSTRING_LINES = 30
# module docstrings allowed to be long: formats, protocols and derivations
LONG_DOC_MODULES = {
    "capture.trigger", "capture.session", "capture.calib_formats", "capture.calibration", "service.config",
    "tracker.imaging.jacobian", "tracker.imaging.contours", "tracker.body.kinematics", "tracker.fitting.cost",
    "tracker.body.model", "tracker.blobs.colour_hull", "service.wire.messages", "service.wire.records", "service.flow.demand",
}
FIGURE = re.compile(r"\d(?:[\d.,]*\d)?\s*(?:ms|mm|px|%|×)(?![A-Za-z0-9])")


def modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the four packages."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            rel = path.relative_to(REPO).with_suffix("")
            parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
            out[".".join(parts)] = path
    return out


def _imports(tree: ast.AST, name: str, known: set[str]) -> list[tuple[str, list[str], int]]:
    """(imported module, names, line) for every import in the module, resolved to modules we know."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                if sub in known:
                    found.append((sub, [], node.lineno))
                elif node.module in known:
                    found.append((node.module, [alias.name], node.lineno))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in known:
                    found.append((alias.name, [], node.lineno))
    return found


def import_graph() -> tuple[dict[str, set[str]], list[str]]:
    """Module -> modules it imports (package faces excluded as targets), and private-name imports."""
    mods = modules()
    known = set(mods)
    graph, private = {}, []
    for name, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        edges = set()
        for target, names, line in _imports(tree, name, known):
            if mods[target].name != "__init__.py":
                edges.add(target)
            for n in names:
                if n.startswith("_") and not n.startswith("__") and target != name:
                    private.append(f"{path.relative_to(REPO)}:{line} imports {target}.{n}")
        graph[name] = edges - {name}
    return graph, private


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
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


def docstring_findings() -> tuple[list[str], list[str]]:
    """Docstrings over MAX_DOCSTRING_LINES lines, and measured figures in tracker/ and segmentation/ docstrings."""
    long, figures = [], []
    for name, path in modules().items():
        tree = ast.parse(path.read_text(), str(path))
        nodes = [tree] + [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))]
        for node in nodes:
            doc = ast.get_docstring(node, clean=False)
            if not doc:
                continue
            where = f"{path.relative_to(REPO)}:{getattr(node, 'lineno', 1)} {getattr(node, 'name', '(module)')}"
            exempt = node is tree and name in LONG_DOC_MODULES
            if len(doc.splitlines()) > MAX_DOCSTRING_LINES and not exempt:
                long.append(f"{where}: {len(doc.splitlines())} lines")
            if name.split(".")[0] in ("tracker", "segmentation") and not exempt:
                hits = FIGURE.findall(doc)
                if hits:
                    figures.append(f"{where}: {', '.join(hits[:4])}")
    return long, figures


if __name__ == "__main__":
    graph, private = import_graph()
    for comp in cycles(graph):
        print("cycle:", " <-> ".join(comp))
    for p in private:
        print("private:", p)
    long, figures = docstring_findings()
    for item in long:
        print("long docstring:", item)
    for item in figures:
        print("figure in docstring:", item)


def face_shadows() -> list[str]:
    """Names a lazy package face exports that are also the name of one of the package's submodules.

    Python binds a submodule to its package's attribute when the submodule is first imported, so such a
    name resolves to the function or to the module depending on import order.
    """
    mods = modules()
    found = []
    for name, path in mods.items():
        if path.name != "__init__.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "_EXPORTS" for t in node.targets):
                exports = ast.literal_eval(node.value)
                found += [f"{name}.{n} (from {module})" for module, names in exports.items() for n in names
                          if f"{name}.{n}" in mods]
    return found
