"""The run log's layout cache: a hit writes the same bytes as probing with rosbags and needs no
type store, a damaged file is probed again, an unwritable folder only loses the cache."""
import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from swerve.tools.logs import bag, layout_cache
from swerve.tools.logs.bag import RunLogWriter, probe_layouts
from swerve.tools.logs.layout_cache import LayoutCache, layouts_key

from . import synthetic

WHEELS = ("fl", "rl", "rr", "fr")


def _write(path: Path, layouts=None, wheels=bag.DEFAULT_WHEELS) -> None:
    meta = {**synthetic.META, "note": "non-ASCII text \u00e9\u2713"}
    with RunLogWriter(path, meta, wheels=wheels, layouts=layouts) as w:
        for rec in synthetic.records(40, seed=3):
            w.write(rec)


def _same_logs(a: Path, b: Path) -> bool:
    return ((a / "metadata.yaml").read_text() == (b / "metadata.yaml").read_text()
            and (a / "log.mcap").read_bytes() == (b / "log.mcap").read_bytes())


@pytest.mark.parametrize("wheels", [bag.DEFAULT_WHEELS, WHEELS])
def test_a_hit_writes_the_bytes_of_probed_layouts(tmp_path, wheels, monkeypatch):
    _write(tmp_path / "probed" / "log", wheels=wheels)
    cache = LayoutCache(tmp_path / "cache")
    _write(tmp_path / "miss" / "log", cache.layouts(wheels), wheels)
    assert (cache.hits, cache.misses) == (0, 1)

    def refuse(*args, **kwargs):
        raise AssertionError("probed although the cache holds the layouts")

    monkeypatch.setattr(layout_cache, "probe_layouts", refuse)
    again = LayoutCache(tmp_path / "cache")
    _write(tmp_path / "hit" / "log", again.layouts(wheels), wheels)
    assert again.hits == 1
    assert _same_logs(tmp_path / "probed" / "log", tmp_path / "miss" / "log")
    assert _same_logs(tmp_path / "probed" / "log", tmp_path / "hit" / "log")


def test_the_data_round_trips(tmp_path):
    layouts = probe_layouts(WHEELS)
    data = json.loads(json.dumps(layouts.as_data()))
    assert bag.LogLayouts.from_data(data).as_data() == layouts.as_data()


def test_other_wheels_are_another_file(tmp_path):
    cache = LayoutCache(tmp_path)
    cache.layouts(bag.DEFAULT_WHEELS)
    cache.layouts(WHEELS)
    assert (cache.hits, cache.misses) == (0, 2) and len(list(tmp_path.glob("runlog-layouts-*.bin"))) == 2


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "empty", "other key", "bad data"])
def test_a_damaged_file_is_probed_again(tmp_path, damage):
    _write(tmp_path / "probed" / "log")
    folder = tmp_path / "cache"
    LayoutCache(folder).layouts()
    (path,) = folder.glob("runlog-layouts-*.bin")
    data = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(data[:len(data) // 2])
    elif damage == "flip":
        i = len(layout_cache.LAYOUT) + 32 + 300
        path.write_bytes(data[:i] + bytes([data[i] ^ 0x01]) + data[i + 1:])
    elif damage == "garbage":
        path.write_bytes(b"not a cache file\n" * 100)
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "other key":          # a whole valid file of other wheels under this name
        LayoutCache(tmp_path / "other").layouts(WHEELS)
        path.write_bytes(next((tmp_path / "other").glob("*.bin")).read_bytes())
    else:                                # checksummed, but a template runs past its bytes
        bad = probe_layouts().as_data()
        bad["templates"]["/odom"]["runs"][0][0] = 10**6
        LayoutCache(folder)._store(layouts_key(), json.dumps(bad).encode())
    cache = LayoutCache(folder)
    _write(tmp_path / "again" / "log", cache.layouts())
    assert _same_logs(tmp_path / "probed" / "log", tmp_path / "again" / "log")
    if damage != "bad data":
        assert (cache.hits, cache.misses) == (0, 1) and LayoutCache(folder).layouts() is not None
        again = LayoutCache(folder)
        again.layouts()
        assert again.hits == 1


def test_an_unwritable_folder_only_loses_the_cache(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder should be")
    cache = LayoutCache(blocker / "swerve")
    _write(tmp_path / "probed" / "log")
    _write(tmp_path / "unkept" / "log", cache.layouts())
    assert cache.misses == 1 and _same_logs(tmp_path / "probed" / "log", tmp_path / "unkept" / "log")


def test_the_key_covers_rosbags_code(tmp_path, monkeypatch):
    key = layouts_key()
    root = Path(layout_cache.importlib.util.find_spec("rosbags").submodule_search_locations[0])
    for part in layout_cache.ROSBAGS_PARTS:
        (tmp_path / part).mkdir()
        for path in (root / part).glob("*.py"):
            (tmp_path / part / path.name).write_bytes(path.read_bytes())
    monkeypatch.setattr(layout_cache.importlib.util, "find_spec",
                        lambda name: SimpleNamespace(submodule_search_locations=[str(tmp_path)]))
    layout_cache._code_digest.cache_clear()
    try:
        assert layouts_key() == key                     # a copy of the same code
        layout_cache._code_digest.cache_clear()
        cdr = tmp_path / "serde" / "cdr.py"
        cdr.write_bytes(cdr.read_bytes() + b"\n# edited\n")
        assert layouts_key() != key
    finally:
        layout_cache._code_digest.cache_clear()


def test_a_hit_imports_no_type_store(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    program = ("import sys; from swerve.core.user_cache import user_cache_dir; "
               "from swerve.tools.logs.layout_cache import LayoutCache; "
               "from swerve.tools.logs.bag import RunLogWriter; "
               "w = RunLogWriter(sys.argv[1], {}, layouts=LayoutCache(user_cache_dir()).layouts()); "
               "w.open(); w.close(); print(sorted(m for m in sys.modules if m.startswith('rosbags.typesys')))")
    first = subprocess.run([sys.executable, "-c", program, str(tmp_path / "a")], env=env, capture_output=True,
                           text=True, check=True)
    second = subprocess.run([sys.executable, "-c", program, str(tmp_path / "b")], env=env, capture_output=True,
                            text=True, check=True)
    assert first.stdout.strip() != "[]"               # the miss built the type store
    assert second.stdout.strip() == "[]"
