"""Where numba caches the compiled kernels (emulator/physics/jit.py): a folder named for the sources."""
import threading
from pathlib import Path

import pytest

from swerve.emulator.physics import coupled, jit, servo_model


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


@pytest.mark.skipif(not jit.ENABLED, reason="numba is not installed (or SWERVE_NO_JIT is set)")
def test_deferred_kernels_run_compiled_inside_warming_in_its_thread_then_for_all_once_switched_on(monkeypatch):
    """What the emulator's child does (:func:`swerve.emulator.child.load_compiled_physics`):
    kernels given their dispatchers run compiled only for the warming thread until switched on."""
    kernels = (servo_model._COMPILED_TICKS, coupled.ROBOT_TICKS)
    for kernel in kernels:
        monkeypatch.setattr(kernel, "_dispatcher", None)
        monkeypatch.setattr(kernel, "_on", False)
    monkeypatch.setattr(jit, "_load_at_first_use", True)
    jit.defer_loading()
    assert not any(k.ready() for k in kernels) and all(k.signatures == [] for k in kernels)
    assert jit.prepare_kernels()
    assert not any(k.ready() for k in kernels)                 # loaded, not on
    seen_elsewhere = []
    with jit.warming():
        assert all(k.ready() for k in kernels)
        other = threading.Thread(target=lambda: seen_elsewhere.extend(k.ready() for k in kernels))
        other.start()
        other.join()
    assert seen_elsewhere == [False, False]                    # another thread (the bus) still runs Python
    assert not any(k.ready() for k in kernels)
    jit.switch_on()
    assert all(k.ready() for k in kernels)


@pytest.mark.skipif(not jit.ENABLED, reason="numba is not installed (or SWERVE_NO_JIT is set)")
def test_kernels_cached_looks_for_numbas_index_of_every_kernel(monkeypatch, tmp_path):
    monkeypatch.setattr(jit, "CACHE_DIR", tmp_path)
    assert not jit.kernels_cached()
    (tmp_path / "physics_x").mkdir()
    (tmp_path / "physics_x" / "servo_model.servo_ticks-509.py311.nbi").touch()
    assert not jit.kernels_cached()                            # the robot's kernel is missing
    (tmp_path / "physics_x" / "coupled.robot_ticks-40.py311.nbi").touch()
    assert jit.kernels_cached()
