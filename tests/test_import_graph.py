"""The layers' import graph, read from the source with :mod:`ast` (nothing is imported).

``swerve.controller`` is numerics: it imports nothing from the driver, the emulator or the
tools. ``swerve.driver`` imports nothing from the controller, the emulator or the tools. No
module anywhere imports a folder by its bare name (``import driver``): the only import package
is ``swerve``.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Folder -> subpackage of ``swerve`` (pyproject.toml's package-dir).
PARTS = ("driver", "emulator", "controller", "tools", "configs")
#: Every Python file the import rules apply to.
SOURCES = sorted(p for d in (*PARTS, "tests", "bench") for p in (ROOT / d).rglob("*.py"))
FORBIDDEN = {
    "controller": ("swerve.driver", "swerve.emulator", "swerve.tools"),
    "driver": ("swerve.controller", "swerve.emulator", "swerve.tools"),
}


def module_name(path: Path) -> str:
    """``swerve.<part>.<...>`` of a file under one of :data:`PARTS`; ``tests.<...>`` etc. else."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(["swerve", *parts] if parts[0] in PARTS else parts)


def imported_modules(path: Path, text: str | None = None) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import statement in a file, nested ones too.

    ``from X import Y`` yields both ``X`` and ``X.Y`` (Y may be a submodule); relative imports
    are resolved against the file's own package. ``text``: the source (default: read the file).
    """
    tree = ast.parse(path.read_text() if text is None else text, filename=str(path))
    pkg = module_name(path).split(".")
    if path.name != "__init__.py":
        pkg = pkg[:-1]
    out = []
    for node in ast.walk(tree):
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


def violations(path: Path, text: str | None = None) -> list[str]:
    """Every broken rule in one file, as ``file:line imports module (why)``."""
    part = path.relative_to(ROOT).parts[0]
    banned = FORBIDDEN.get(part, ())
    bad = []
    for line, mod in imported_modules(path, text):
        where = f"{path.relative_to(ROOT)}:{line} imports {mod}"
        if mod.split(".")[0] in PARTS:
            bad.append(f"{where} (a bare folder name; import swerve.{mod})")
        elif any(mod == b or mod.startswith(b + ".") for b in banned):
            bad.append(f"{where} (swerve.{part} must not depend on it)")
    return sorted(set(bad))


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
    assert violations(probe, "from swerve.configs.errors import ConfigError\n"
                             "from .kinematics import Geometry\nimport numpy as np\n") == []
