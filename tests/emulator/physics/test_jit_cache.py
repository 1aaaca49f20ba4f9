"""Where numba caches the compiled kernels (emulator/physics/jit.py): a folder named for the sources."""
from pathlib import Path

import pytest

from swerve.emulator.physics import jit


def test_the_cache_folder_is_named_for_the_sources(monkeypatch, tmp_path):
    digest = jit._sources_digest()
    assert jit.CACHE_DIR.name == f"kernels-{digest}"
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    package = tmp_path / "physics"
    package.mkdir()
    monkeypatch.setattr(jit, "PACKAGE_DIR", package)                     # a checkout: next to the sources
    assert jit._cache_dir(digest) == package / "__pycache__" / "numba" / f"kernels-{digest}"
    monkeypatch.setattr(jit.os, "access", lambda path, mode: False)     # installed read-only: the user's cache
    assert jit._cache_dir(digest) == tmp_path / "xdg" / "swerve" / "numba" / f"kernels-{digest}"
    monkeypatch.undo()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))          # the user's folder holds ours
    assert jit._cache_dir(digest) == tmp_path / "mine" / f"kernels-{digest}"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine" / f"kernels-{digest}"))   # inherited: kept
    assert jit._cache_dir(digest) == tmp_path / "mine" / f"kernels-{digest}"


def test_an_edit_of_any_physics_source_or_the_reference_table_renames_the_folder(monkeypatch, tmp_path):
    package = tmp_path / "physics"
    package.mkdir()
    for p in jit.PACKAGE_DIR.glob("*.py"):
        (package / p.name).write_bytes(p.read_bytes())
    table = tmp_path / f"{jit.REFERENCE_MODEL}.yaml"
    table.write_bytes((jit.MODELS_DIR / table.name).read_bytes())
    monkeypatch.setattr(jit, "PACKAGE_DIR", package)
    monkeypatch.setattr(jit, "MODELS_DIR", tmp_path)
    digests = {jit._sources_digest()}
    assert digests == {jit._sources_digest()}                             # the same sources, the same name
    for edited in (package / "firmware.py", package / "contact.py", table):
        edited.write_bytes(edited.read_bytes() + b"\n# edited\n")
        digests.add(jit._sources_digest())
    assert len(digests) == 4


def test_a_helper_outside_the_package_is_refused():
    def kernel(x):
        return x

    with pytest.raises(ValueError, match="outside"):
        jit.compiled(kernel, depends=(str(Path(jit.__file__).parents[2] / "driver" / "bus.py"),))
