"""The layers' import graph, read from the source with :mod:`ast` (nothing is imported).

Every import statement counts, at the top of a module or inside a function. The layers, from
the bottom: ``swerve.core`` (errors, option texts, atomic writes, fixed-order numerics) imports
nothing else of swerve; ``swerve.configs`` imports the core; ``swerve.driver`` and
``swerve.controller`` (numerics) import the configs and the core; ``swerve.emulator`` imports
the driver, the configs and the core; ``swerve.tools`` (the application) may import every layer.
No exception is allowed.

No package's parts import each other in a circle (modules and subpackages as nodes, in-function
imports included; imports under ``if TYPE_CHECKING:`` never run and do not count). No module
anywhere imports a folder by its bare name (``import driver``): the only import package is
``swerve``.
"""
from __future__ import annotations

import ast
import collections
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Folder -> subpackage of ``swerve`` (pyproject.toml's package-dir).
PARTS = ("driver", "emulator", "controller", "tools", "configs", "core")
#: Every Python file the import rules apply to.
SOURCES = sorted(p for d in (*PARTS, "tests", "bench") for p in (ROOT / d).rglob("*.py"))
#: The parts of ``swerve`` each layer may import (its own part always).
ALLOWED = {
    "core": (),
    "configs": ("swerve.core",),
    "driver": ("swerve.configs", "swerve.core"),
    "controller": ("swerve.configs", "swerve.core"),
    "emulator": ("swerve.driver", "swerve.configs", "swerve.core"),
    "tools": ("swerve",),
}
#: Cross-layer imports allowed in one file only: ``(file, module) -> why``. A ``from`` import
#: of the module through its package (``from swerve.core import small_linalg``) counts.


def module_name(path: Path) -> str:
    """``swerve.<part>.<...>`` of a file under one of :data:`PARTS`; ``tests.<...>`` etc. else."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(["swerve", *parts] if parts[0] in PARTS else parts)


def _type_checking_only(tree: ast.AST) -> set[int]:
    """``id`` of every node inside an ``if TYPE_CHECKING:`` block (imports for annotations only)."""
    inside: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and (
                (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING")
                or (isinstance(node.test, ast.Attribute) and node.test.attr == "TYPE_CHECKING")):
            inside.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return inside


def imported_modules(path: Path, text: str | None = None, *,
                     runtime_only: bool = False) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import statement in a file, nested ones too.

    ``from X import Y`` yields both ``X`` and ``X.Y`` (Y may be a submodule); relative imports
    are resolved against the file's own package. ``text``: the source (default: read the file).
    ``runtime_only``: leave out the imports under ``if TYPE_CHECKING:``, which never run.
    """
    tree = ast.parse(path.read_text() if text is None else text, filename=str(path))
    pkg = module_name(path).split(".")
    if path.name != "__init__.py":
        pkg = pkg[:-1]
    skip = _type_checking_only(tree) if runtime_only else set()
    out = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(pkg[:len(pkg) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module
            out.append((node.lineno, base))
            out += [(node.lineno, f"{base}.{a.name}") for a in node.names if a.name != "*"]
    return out


def _within(mod: str, package: str) -> bool:
    return mod == package or mod.startswith(package + ".")


def violations(path: Path, text: str | None = None) -> list[str]:
    """Every broken rule in one file, as ``file:line imports module (why)``."""
    rel = path.relative_to(ROOT)
    part = rel.parts[0]
    allowed = (f"swerve.{part}", *ALLOWED[part]) if part in ALLOWED else ("swerve",)
    imports = imported_modules(path, text)
    bad = []
    for line, mod in imports:
        where = f"{rel}:{line} imports {mod}"
        if mod.split(".")[0] in PARTS:
            bad.append(f"{where} (a bare folder name; import swerve.{mod})")
        elif _within(mod, "swerve") and not any(_within(mod, a) for a in allowed):
            bad.append(f"{where} (swerve.{part} must not depend on it)")
    return sorted(set(bad))


def import_edges(sources: dict[str, Path] | None = None,
                 texts: dict[str, str] | None = None) -> set[tuple[str, str]]:
    """``(importer, imported)`` between the ``swerve`` modules of ``sources`` (module name ->
    file; default: every file under :data:`PARTS`), each import resolved to the module it names
    (``from X import Y`` is ``X.Y`` where that is a module, else ``X``). ``texts``: sources to
    use instead of reading some files."""
    if sources is None:
        sources = {module_name(p): p for p in SOURCES if p.relative_to(ROOT).parts[0] in PARTS}
    texts = texts or {}
    edges = set()
    for name, path in sources.items():
        for _, mod in imported_modules(path, texts.get(name), runtime_only=True):
            if mod in sources and mod != name:
                edges.add((name, mod))
    return edges


def cycles(edges: set[tuple[str, str]]) -> list[tuple[str, tuple[str, ...]]]:
    """The import circles among the parts of each package: ``(package, parts in the circle)``.

    For every package, its direct children (modules and subpackages, a subpackage standing for
    everything under it) are the nodes, and a module of one child importing a module of another
    is an edge; each strongly connected set of two or more children is a circle. A circle among
    modules shows up at the innermost package that holds them all.
    """
    names = {m for e in edges for m in e}
    packages = {".".join(m.split(".")[:k]) for m in names for k in range(1, m.count(".") + 1)}
    found = []
    for pkg in sorted(packages):
        depth = pkg.count(".") + 2

        def child(mod: str, pkg=pkg, depth=depth) -> str | None:
            return ".".join(mod.split(".")[:depth]) if mod.startswith(pkg + ".") else None

        graph: dict[str, set[str]] = collections.defaultdict(set)
        for a, b in edges:
            ca, cb = child(a), child(b)
            if ca and cb and ca != cb:
                graph[ca].add(cb)
        found += [(pkg, comp) for comp in _strongly_connected(graph) if len(comp) > 1]
    return found


def _strongly_connected(graph: dict[str, set[str]]) -> list[tuple[str, ...]]:
    """Tarjan's strongly connected components of ``graph``, each sorted (iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, succ = work[-1]
            for nxt in succ:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        m = stack.pop()
                        on_stack.discard(m)
                        comp.append(m)
                        if m == node:
                            break
                    out.append(tuple(sorted(comp)))
    return out


def test_the_sources_are_found():
    names = {p.relative_to(ROOT).as_posix() for p in SOURCES}
    assert {"controller/tracking.py", "driver/bus.py", "tools/run/loop.py",
            "tests/test_import_graph.py"} <= names


@pytest.mark.parametrize("part", [*PARTS, "tests", "bench"])
def test_every_module_keeps_the_import_rules(part):
    files = [p for p in SOURCES if p.relative_to(ROOT).parts[0] == part]
    assert files
    assert [v for p in files for v in violations(p)] == []


@pytest.mark.parametrize("part, text, expected", [
    ("controller", "from swerve.driver.errors import ServoError\n", "swerve.driver.errors"),
    ("controller", "def f():\n    import swerve.tools.cli\n", "swerve.tools.cli"),
    ("controller", "from ..emulator import server\n", "swerve.emulator"),
    ("driver", "from swerve.controller.kinematics import Geometry\n", "swerve.controller.kinematics"),
    ("driver", "import swerve.tools.run.loop as loop\n", "swerve.tools.run.loop"),
    ("tools", "import driver.bus\n", "driver.bus"),
    ("tests", "from configs import shipped\n", "configs"),
])
def test_the_checker_reports_a_planted_violation(part, text, expected):
    probe = ROOT / part / "probe_module.py"
    found = violations(probe, text)
    assert any(f" imports {expected} " in v for v in found), found


def test_the_checker_accepts_allowed_imports():
    probe = ROOT / "controller" / "probe_module.py"
    assert violations(probe, "from swerve.core.errors import ConfigError\n"
                             "from .kinematics import Geometry\nimport numpy as np\n") == []


@pytest.mark.parametrize("part, text, expected", [
    ("configs", "from swerve.driver.errors import DxlError\n", "swerve.driver.errors"),
    ("driver", "def f():\n    from swerve.emulator import server\n", "swerve.emulator"),
    ("emulator", "from swerve.controller.kinematics import Geometry\n", "swerve.controller.kinematics"),
    ("emulator", "def f():\n    import swerve.tools.cli\n", "swerve.tools.cli"),
])
def test_the_checker_reports_a_planted_layer_violation(part, text, expected):
    found = violations(ROOT / part / "probe_module.py", text)
    assert any(f" imports {expected} " in v for v in found), found


def test_no_import_cycles():
    assert cycles(import_edges()) == []


def test_the_cycle_finder_reports_a_planted_circle_through_a_function():
    text = (ROOT / "driver" / "packets.py").read_text() + "\n\ndef _probe():\n    from swerve.driver.bus import Bus\n"
    edges = import_edges(texts={"swerve.driver.packets": text})
    assert ("swerve.driver.packets", "swerve.driver.bus") in edges
    circles = [c for pkg, c in cycles(edges) if pkg == "swerve.driver"]
    assert len(circles) == 1 and {"swerve.driver.bus", "swerve.driver.packets"} <= set(circles[0]), circles


def test_the_cycle_finder_sees_circles_between_subpackages():
    edges = {("swerve.a.x.m", "swerve.a.y.n"), ("swerve.a.y.k", "swerve.a.x.j"), ("swerve.b", "swerve.a.x.m")}
    assert cycles(edges) == [("swerve.a", ("swerve.a.x", "swerve.a.y"))]
    assert cycles(edges - {("swerve.a.y.k", "swerve.a.x.j")}) == []


def test_an_import_for_annotations_only_is_no_cycle_edge():
    """``if TYPE_CHECKING:`` imports never run, so they close no circle; the same import at
    run time does."""
    src = (ROOT / "driver" / "packets.py").read_text()
    typed = src + "\n\nfrom typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from swerve.driver.bus import Bus\n"
    assert ("swerve.driver.packets", "swerve.driver.bus") not in import_edges(texts={"swerve.driver.packets": typed})
    plain = src + "\n\nfrom swerve.driver.bus import Bus\n"
    assert ("swerve.driver.packets", "swerve.driver.bus") in import_edges(texts={"swerve.driver.packets": plain})
