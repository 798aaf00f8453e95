"""The house rules of the tree, measured: import cycles, imports inside functions, long files.

    python tools/house.py            # a report; exit status 1 if a rule is broken
    python tools/house.py --json     # the same as JSON

- **Import cycles** among the modules of ``clrecon`` (strongly connected components of the
  import graph), counting every import, those inside functions too: a function-level import
  that closes a cycle is a cycle all the same, only deferred. An import of ``a.b.c`` is an
  edge to ``a.b.c`` (Python runs the packages' ``__init__`` too, but a package that imports
  its own submodules is not a cycle of design).
- **Imports inside functions** of ``clrecon`` modules, outside the CLI (whose commands import
  their subsystem on use, to start fast); each is listed.
- **Long files**: Python (library, tests, tools) and OpenCL C files over ``MAX_LINES``.

``tests/unit/test_house.py`` asserts the first and the last; the count of function-level
imports is reported, not enforced.
"""
from __future__ import annotations

import argparse
import ast
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the longest a source file may be (the issue's "about 400 lines")
MAX_LINES = 400
#: where long files are looked for, and their endings
LENGTH_DIRS = ("clrecon", "tests", "tools", "kernels")
LENGTH_SUFFIXES = (".py", ".cl", ".h")


def modules(root: Path = ROOT) -> dict[str, Path]:
    """``{dotted module name: path}`` of every module of the ``clrecon`` package."""
    out = {}
    for path in sorted((root / "clrecon").rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _targets(node: ast.AST, package: str, known: dict[str, Path]) -> list[str]:
    """The ``clrecon`` modules an import statement names (the longest known prefix)."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = node.module or ""
        if node.level:
            parts = package.split(".")
            parts = parts[:len(parts) - node.level + 1]
            base = ".".join(parts + ([base] if base else []))
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                 for a in node.names]
    out = []
    for name in names:
        while name not in known and "." in name:
            name = name.rsplit(".", 1)[0]
        if name in known:
            out.append(name)
    return out


def import_graph(root: Path = ROOT) -> tuple[dict[str, set[str]], dict[str, list[str]]]:
    """``(graph, local)``: each module's imported ``clrecon`` modules (every import), and
    the function-level imports of each module as ``"line: module"`` strings."""
    known = modules(root)
    graph: dict[str, set[str]] = {}
    local: dict[str, list[str]] = {}
    for name, path in known.items():
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        tree = ast.parse(path.read_text(), str(path))
        deps: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                deps.update(_targets(node, package, known))
        graph[name] = deps - {name}
        found = []
        for fn in ast.walk(tree):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(fn):
                    if isinstance(node, (ast.Import, ast.ImportFrom)):
                        found += [f"{node.lineno}: {t}"
                                  for t in _targets(node, package, known) if t != name]
        if found:
            local[name] = sorted(set(found), key=lambda s: int(s.split(":")[0]))
    return graph, local


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
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
    return out


def long_files(root: Path = ROOT, limit: int = MAX_LINES) -> list[tuple[str, int]]:
    """``(path, lines)`` of every tracked-looking source file over ``limit`` lines."""
    out = []
    for folder in LENGTH_DIRS:
        for path in sorted((root / folder).rglob("*")):
            if path.suffix in LENGTH_SUFFIXES and path.is_file():
                n = len(path.read_text(errors="replace").splitlines())
                if n > limit:
                    out.append((str(path.relative_to(root)), n))
    return out


def report(root: Path = ROOT) -> dict:
    graph, local = import_graph(root)
    outside_cli = {k: v for k, v in local.items() if not k.startswith("clrecon.cli")}
    return {"modules": len(graph), "cycles": cycles(graph),
            "function_level_imports": sum(len(v) for v in outside_cli.values()),
            "function_level_imports_by_module": outside_cli,
            "function_level_imports_cli": sum(len(v) for k, v in local.items()
                                              if k.startswith("clrecon.cli")),
            "max_lines": MAX_LINES, "long_files": long_files(root)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    args = p.parse_args(argv)
    r = report()
    if args.json:
        print(json.dumps(r, indent=1))
    else:
        print(f"{r['modules']} modules; import cycles: {len(r['cycles'])}")
        for comp in r["cycles"]:
            print(f"  cycle of {len(comp)}: {', '.join(comp)}")
        print(f"imports inside functions outside the CLI: {r['function_level_imports']} "
              f"(CLI: {r['function_level_imports_cli']})")
        for mod, lines in r["function_level_imports_by_module"].items():
            print(f"  {mod}: {'; '.join(lines)}")
        print(f"files over {r['max_lines']} lines: {len(r['long_files'])}")
        for path, n in r["long_files"]:
            print(f"  {path}: {n}")
    return 1 if r["cycles"] or r["long_files"] else 0


if __name__ == "__main__":
    sys.exit(main())
