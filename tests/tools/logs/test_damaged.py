"""A log damaged mid-file: what is intact is read, the damage is named by byte offset, the command fails."""
import shutil
import struct

import pytest

from swerve.core.errors import ConfigError
from swerve.tools.cli import main
from swerve.tools.logs.bag import read_log


def _chunk_offsets(mcap_bytes: bytes) -> list[int]:
    """Byte offsets of the top-level Chunk records (opcode 0x06) of an MCAP file."""
    pos, out = 8, []
    while pos + 9 <= len(mcap_bytes):
        op = mcap_bytes[pos]
        (length,) = struct.unpack_from("<Q", mcap_bytes, pos + 1)
        if op == 0x06:
            out.append(pos)
        if op == 0x02:
            break
        pos += 9 + length
    return out


@pytest.fixture
def damaged(tmp_path, run_bag):
    """A copy of the 500-cycle run with the header of the chunk in the middle overwritten;
    returns ``(bag, byte offset of the damage)``."""
    bag = tmp_path / "damaged"
    shutil.copytree(run_bag, bag)
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    chunks = _chunk_offsets(bytes(data))
    at = chunks[len(chunks) // 2]
    data[at:at + 24] = b"\xa5" * 24
    mcap.write_bytes(bytes(data))
    return bag, at


def test_a_damaged_log_keeps_every_intact_cycle_and_names_the_offset(damaged, run_records):
    bag, at = damaged
    log = read_log(bag)
    assert [d.offset for d in log.damage] == [at]
    assert not log.clean
    # one chunk lost, at most a few cycles; the cycles after the damage are read too
    assert len(run_records) - 5 <= len(log) < len(run_records)
    assert log.cycle[-1] == len(run_records) - 1
    assert f"damaged at byte {at}" in log.recovery_note


def test_export_csv_writes_the_intact_cycles_and_fails_naming_the_offset(damaged, tmp_path, capsys):
    bag, at = damaged
    out = tmp_path / "d.csv"
    assert main(["export-csv", str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"damaged at byte {at}" in err[0]
    rows = out.read_text().splitlines()
    assert len(rows) - 1 == len(read_log(bag))


def test_garbage_and_a_cut_header_are_one_line_errors(tmp_path, run_bag, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x00" * 1000)
    with pytest.raises(ConfigError, match="not an MCAP file"):
        read_log(junk)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(next(run_bag.glob("*.mcap")).read_bytes()[:20])
    assert main(["export-csv", str(cut), "--out", str(tmp_path / "c.csv")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not (tmp_path / "c.csv").exists()
