"""``swerve scan`` against the emulator: table output, clear errors."""
from __future__ import annotations

import pytest

from swerve.tools.cli import main


def test_scan_lists_servos(emu, capsys):
    assert main(["scan", "--port", emu.port, "--ids", "0-10", "--timeout-margin-ms", "300"]) == 0
    out = capsys.readouterr().out
    lines = [l.split() for l in out.splitlines() if l.strip()[:1].isdigit()]
    assert [int(l[0]) for l in lines] == list(range(1, 9))
    assert all(l[1:3] == ["XH430-W210", "1010"] for l in lines)


def test_scan_nothing_answers(emu, capsys):
    for i in range(1, 9):
        emu.faults.vanish(i)
    assert main(["scan", "--port", emu.port, "--ids", "1-3", "--timeout-margin-ms", "50"]) == 2
    err = capsys.readouterr().err
    assert "no servo answered" in err and "IDs 1-3" in err


def test_scan_bad_port(capsys):
    assert main(["scan", "--port", "/dev/no-such-port"]) == 2
    assert "/dev/no-such-port" in capsys.readouterr().err


@pytest.mark.parametrize("ids", ["5-2", "0-300", "abc"])
def test_scan_bad_id_range(ids, capsys):
    with pytest.raises(SystemExit) as ei:
        main(["scan", "--port", "loop://", "--ids", ids])
    assert ei.value.code == 2
    assert "ID range" in capsys.readouterr().err


def test_scan_all_bauds_finds_servos_at_57600(hw_port, capsys):
    if hw_port:
        pytest.skip("needs the emulator")
    build_emulator = pytest.importorskip("swerve.emulator.factory").build_emulator
    Frozen = pytest.importorskip("swerve.emulator.timing").Frozen
    with build_emulator(ids=[1, 2], baud=57_600, timing=Frozen()) as emu:
        assert main(["scan", "--port", emu.port, "--all-bauds", "--ids", "1-2",
                     "--timeout-margin-ms", "50"]) == 0
    out = capsys.readouterr().out
    assert "at 57600 bps: 2 servo(s)" in out
    assert "1000000 bps: no servo" in out
