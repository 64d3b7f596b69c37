"""docs/architecture.md's table of rooms says what each room imports: checked against the real import graph.

The graph is read by grimp (import-linter's) from the package laid out as a wheel installs it (test_layers.py
says why), a room being a top-level module of ``mi_nest``. The table's "imports" cell names the rooms a room
imports; clauses that begin with "never" or "no" name what it must not, and are left out.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from test_layers import installed_layout

ROOT = Path(__file__).resolve().parents[1]
GRAPH = """
import collections, json, grimp
graph = grimp.build_graph("mi_nest")
room = lambda module: module.split(".")[1] if "." in module else None
edges = collections.defaultdict(set)
for module in graph.modules:
    for imported in graph.find_modules_directly_imported_by(module):
        if imported.startswith("mi_nest.") and room(module) and room(imported) != room(module):
            edges[room(module)].add(room(imported))
modules = {m: sorted(i for i in graph.find_modules_directly_imported_by(m) if i.startswith("mi_nest."))
           for m in graph.modules}
print(json.dumps({"rooms": sorted({room(m) for m in graph.modules if room(m)}),
                  "edges": {k: sorted(v) for k, v in edges.items()}, "modules": modules}))
"""


def import_graph(tmp_path) -> dict:
    """``rooms``, ``edges`` (room -> the rooms it imports) and ``modules`` (module -> the modules it imports,
    ``TYPE_CHECKING`` imports included)."""
    result = subprocess.run([sys.executable, "-c", GRAPH], cwd=installed_layout(tmp_path), capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def real_imports(tmp_path) -> tuple[list[str], dict[str, list[str]]]:
    graph = import_graph(tmp_path)
    return graph["rooms"], graph["edges"]


def documented_imports(rooms: list[str]) -> dict[str, set[str]]:
    """Room -> the rooms its row's imports cell names."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    table = text.split("## Rooms", 1)[1].split("\n## ", 1)[0]
    documented = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not cells[0].startswith("`"):
            continue
        named = re.findall(r"`(?:mi_nest/)?([a-z_]+)(?:/|\.py)`", cells[0])
        kept = [clause for clause in cells[-1].split(";") if not re.match(r"\s*(never|no)\b", clause, re.I)]
        imports = {r for r in rooms if any(re.search(rf"(?<![\w/.-]){r}(?![\w/-])", c) for c in kept)}
        for room in named:
            documented[room] = imports - {room}
    return documented


def test_the_architecture_table_names_what_each_room_imports(tmp_path):
    rooms, edges = real_imports(tmp_path)
    documented = documented_imports(rooms)
    missing_rows = sorted(set(rooms) - set(documented) - {"scenes"})
    assert not missing_rows, f"docs/architecture.md has no row for {missing_rows}"
    wrong = {room: {"imported, not named": sorted(set(edges.get(room, ())) - named),
                    "named, not imported": sorted(named - set(edges.get(room, ())))}
             for room, named in documented.items() if named != set(edges.get(room, ()))}
    assert not wrong, f"docs/architecture.md's imports column disagrees with the code: {wrong}"


def import_circle(modules: dict[str, list[str]]) -> list[str] | None:
    """A chain of imports that comes back to its first module, or None (depth-first search)."""
    done, path = set(), []

    def visit(module):
        if module in path:
            return path[path.index(module):] + [module]
        if module in done:
            return None
        path.append(module)
        for imported in modules.get(module, ()):
            circle = visit(imported)
            if circle:
                return circle
        path.pop()
        done.add(module)
        return None
    return next((circle for circle in map(visit, sorted(modules)) if circle), None)


def test_no_module_imports_itself_back(tmp_path):
    assert import_circle({"a": ["b"], "b": ["c"], "c": ["a"]}) == ["a", "b", "c", "a"]     # the search finds one
    assert import_circle({"a": ["b", "c"], "b": ["c"], "c": []}) is None
    assert import_circle(import_graph(tmp_path)["modules"]) is None
