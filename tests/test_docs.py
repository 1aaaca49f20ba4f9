"""The documents against the tree: links and paths exist, the README's examples run, every
command and benchmark is documented."""
from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

from swerve.tools.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BENCHMARKS = ROOT / "BENCHMARKS.md"
#: The top-level pages, docs/ and every part's README: their relative links must resolve, and each
#: path of the tree they name in backticks (`driver/bus.py`) must exist.
PAGES = sorted({README, BENCHMARKS, *(ROOT / "docs").rglob("*.md"),
                *(p for d in ("driver", "emulator", "controller", "tools", "configs", "testing", "bench")
                  for p in (ROOT / d).rglob("README.md"))})
TOP_FOLDERS = ("driver", "emulator", "controller", "tools", "configs", "testing", "tests", "bench", "docs")

LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
CODE_PATH = re.compile(r"`((?:%s)/[A-Za-z0-9_./-]*)`" % "|".join(TOP_FOLDERS))
FENCE = re.compile(r"```(\w*)\n(.*?)```", re.S)


def _rel(page: Path) -> str:
    return str(page.relative_to(ROOT))


def relative_links(text: str) -> list[str]:
    """Targets of the Markdown links in ``text`` that point into the tree (no URL, no bare anchor)."""
    out = []
    for target in LINK.findall(text):
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue
        out.append(target.split("#", 1)[0])
    return out


def test_link_finder_sees_relative_links_only():
    text = "[a](docs/x.md#s) [b](https://e.org/y) [c](#anchor) [d](../up.md) `e` [f](mailto:x@y)"
    assert relative_links(text) == ["docs/x.md", "../up.md"]


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_relative_links_point_to_files(page):
    missing = [t for t in relative_links(page.read_text(encoding="utf-8"))
               if not (page.parent / t).exists()]
    assert not missing, f"{_rel(page)} links to missing files: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_named_paths_exist(page):
    """A path of the tree written in backticks names a file or folder that is there."""
    missing = sorted({p for p in CODE_PATH.findall(page.read_text(encoding="utf-8"))
                      if not (ROOT / p.rstrip("/")).exists()})
    assert not missing, f"{_rel(page)} names paths that do not exist: {missing}"


def _blocks(text: str, lang: str) -> list[str]:
    return [body for kind, body in FENCE.findall(text) if kind == lang]


def test_readme_api_example_runs_and_drives_the_robot_forward(tmp_path):
    """The README's first Python block, run as it is: two seconds at 0.1 m/s move the emulated
    robot about 0.2 m along x, and the drive servos report about 0.1 m/s / r."""
    code = _blocks(README.read_text(encoding="utf-8"), "python")[0]
    script = tmp_path / "example.py"
    script.write_text(code)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    last = done.stdout.strip().splitlines()[-1]               # "(v, v, v, v) (x, y, theta)"
    speeds, pose = ast.literal_eval(last.replace(") (", "), ("))
    assert len(speeds) == 4 and all(2.8 < v < 3.2 for v in speeds)     # 0.1 m/s over r = 0.033 m
    x, y, theta = pose
    assert 0.18 < x < 0.21 and abs(y) < 0.005 and abs(theta) < 0.01


def test_readme_plugin_example_is_the_one_the_tests_run():
    """The pytest-plugin example in the README is pasted from tests/testing/test_testing_plugin.py."""
    example = _blocks(README.read_text(encoding="utf-8"), "python")[1]
    assert "emulated_bus" in example and "emulated_robot" in example
    def squeeze(code: str) -> str:
        return re.sub(r"\n\s*\n+", "\n", code.strip())     # blank lines do not count

    assert squeeze(example) in squeeze((ROOT / "tests" / "testing" / "test_testing_plugin.py").read_text(encoding="utf-8"))


def test_readme_lists_every_subcommand():
    text = README.read_text(encoding="utf-8")
    first_cells = re.findall(r"^\| (`swerve [^|]*)\|", text, re.M)
    rows = {name for cell in first_cells for name in re.findall(r"`swerve ([a-z-]+)", cell)}
    assert {name.replace("_", "-") for name in COMMANDS} <= rows


def test_every_benchmark_has_a_section_in_benchmarks_md():
    text = BENCHMARKS.read_text(encoding="utf-8")
    benches = sorted(p.name for p in (ROOT / "bench").glob("bench_*.py"))
    assert benches
    missing = [name for name in benches if f"bench/{name}" not in text]
    assert not missing, f"BENCHMARKS.md does not mention {missing}"
