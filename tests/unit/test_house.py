"""The house rules hold: no import cycle among clrecon's modules (function-level imports
counted), and no source file over tools/house.py's MAX_LINES."""
from __future__ import annotations

import textwrap
from pathlib import Path

from tool_module import load_tool

house = load_tool("house")


def test_no_import_cycle():
    graph, _ = house.import_graph()
    found = house.cycles(graph)
    assert not found, f"import cycles: {found}"


def test_no_long_source_file():
    assert not house.long_files(), f"files over {house.MAX_LINES} lines"


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    return tmp_path


def test_checker_finds_a_cycle_closed_inside_a_function(tmp_path):
    root = _tree(tmp_path, {
        "clrecon/__init__.py": "",
        "clrecon/a.py": "from clrecon.b import x\n",
        "clrecon/b.py": "x = 1\n\ndef f():\n    from clrecon import a\n    return a\n",
        "clrecon/c.py": "import clrecon.a\n",
    })
    graph, local = house.import_graph(root)
    assert house.cycles(graph) == [["clrecon.a", "clrecon.b"]]
    assert local == {"clrecon.b": ["4: clrecon.a"]}


def test_checker_resolves_relative_imports_and_counts_lines(tmp_path):
    root = _tree(tmp_path, {
        "clrecon/__init__.py": "",
        "clrecon/p/__init__.py": "from . import q\n",
        "clrecon/p/q.py": "from ..p import r\n",
        "clrecon/p/r.py": "from .q import *\n",
        "tools/long.py": "x = 1\n" * (house.MAX_LINES + 1),
        "tools/short.py": "x = 1\n" * house.MAX_LINES,
    })
    graph, _ = house.import_graph(root)
    assert graph["clrecon.p"] == {"clrecon.p.q"}
    assert house.cycles(graph) == [["clrecon.p.q", "clrecon.p.r"]]
    assert house.long_files(root) == [("tools/long.py", house.MAX_LINES + 1)]
