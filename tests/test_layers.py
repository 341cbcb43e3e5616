"""The package's import graph follows the layers of docs/README.md ("Layers"): every module is in
a layer's subpackage, imports only from its own subpackage and the layers before it, and no import
cycle exists (function-level imports included: they hide a cycle, they do not break it). The
package's own ``__init__`` is the public face above every layer and is not in the line."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dualarm_mpc"


def layers() -> list[set[str]]:
    """The layer line of docs/README.md: layers (subpackages) split by →, several in one layer by
    commas."""
    text = (ROOT / "docs" / "README.md").read_text()
    section = text.split("## Layers", 1)[1].split("\n## ", 1)[0]
    (line,) = re.findall(r"`([^`]*→[^`]*)`", section, re.S)
    return [{m.strip() for m in layer.split(",")} for layer in " ".join(line.split()).split("→")]


def unit(module: str) -> str:
    """A module's layer: its subpackage."""
    return module.split(".")[0]


def imports() -> dict[str, set[str]]:
    """Module (dotted, under the package) → the package's modules it imports, anywhere in it."""
    modules = {".".join(p.relative_to(PACKAGE).with_suffix("").parts): p
               for p in PACKAGE.rglob("*.py") if p.name != "__init__.py"}
    graph = {}
    for name, path in modules.items():
        found = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                    node.module.split(".")[0] == "dualarm_mpc":
                sub = node.module.removeprefix("dualarm_mpc").lstrip(".")
                found |= {sub} if sub else {a.name for a in node.names}
            elif isinstance(node, ast.Import):
                found |= {a.name.removeprefix("dualarm_mpc.") for a in node.names
                          if a.name.startswith("dualarm_mpc.")}
        graph[name] = {m for m in found if m in modules}
    return graph


def test_every_module_is_in_one_layer() -> None:
    placed = [m for layer in layers() for m in layer]
    assert len(placed) == len(set(placed)), "a module in two layers"
    units = {unit(m) for m in imports()}
    assert not units - set(placed), f"in no layer of docs/README.md: {sorted(units - set(placed))}"
    assert not set(placed) - units, f"no such module: {sorted(set(placed) - units)}"


def test_modules_import_only_from_lower_layers() -> None:
    rank = {m: k for k, layer in enumerate(layers()) for m in layer}
    wrong = sorted(f"{a} imports {b}" for a, deps in imports().items() for b in deps
                   if unit(a) != unit(b) and rank[unit(b)] >= rank[unit(a)])
    assert not wrong, "imports against the layers of docs/README.md: " + "; ".join(wrong)


LONG = 500  # lines: a longer module says why it is one module (issue 48)


def test_a_long_module_says_why_it_is_one() -> None:
    unexplained = sorted(str(p.relative_to(ROOT)) for p in PACKAGE.rglob("*.py")
                         if len(p.read_text().splitlines()) > LONG
                         and "Why one module" not in (ast.get_docstring(ast.parse(p.read_text()))
                                                      or ""))
    assert not unexplained, f"over {LONG} lines without 'Why one module': {unexplained}"


def test_no_import_cycle() -> None:
    graph = imports()
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for d in sorted(graph[m]):
            assert state.get(d) != 1, "import cycle: " + " → ".join([*path, m, d])
            if d not in state:
                visit(d, [*path, m])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
