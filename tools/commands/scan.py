"""``swerve scan``: list every servo on a port (ID, model, model number, firmware)."""
from __future__ import annotations

import argparse

from swerve.core.errors import ConfigError
from swerve.core.options import parse_id_range
from swerve.driver.bus import Bus
from swerve.driver.control_table import ID_MAX, SCAN_BAUDS_BPS
from swerve.driver.errors import DxlError
from swerve.tools.argtypes import baud_rate, finite_float


def _id_range(text: str) -> range:
    """``"0-252"`` or ``"5"`` -> a range of IDs."""
    try:
        return parse_id_range(text, max_id=ID_MAX)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True, help="serial port or URL, e.g. /dev/ttyUSB0 or a pty path")
    parser.add_argument("--baud", type=baud_rate, default=1_000_000, help="baud rate (default 1000000)")
    parser.add_argument("--all-bauds", action="store_true",
                        help="try every standard X-series baud rate (57600 first)")
    parser.add_argument("--ids", type=_id_range, default=range(0, 253), metavar="LO-HI",
                        help="ID range to scan (default 0-252)")
    parser.add_argument("--no-broadcast", action="store_true", help="ping each ID only (slower)")
    parser.add_argument("--timeout-margin-ms", type=finite_float(0.0, 10_000.0), default=2.0,
                        help="extra wait per reply in ms (raise for slow adapters or emulators)")


def run(args: argparse.Namespace) -> int:
    bauds = SCAN_BAUDS_BPS if args.all_bauds else (args.baud,)
    total = 0
    for baud in bauds:
        with Bus(args.port, baud, timeout_margin_s=args.timeout_margin_ms * 1e-3) as bus:
            found = bus.scan(args.ids, broadcast=not args.no_broadcast)
        if not found:
            if args.all_bauds:
                print(f"{baud:>8} bps: no servo")
            continue
        total += len(found)
        print(f"{args.port} at {baud} bps: {len(found)} servo(s)")
        print(f"{'ID':>4}  {'model':<14} {'number':>6}  {'firmware':>8}")
        for r in found:
            print(f"{r.id:>4}  {r.model:<14} {r.model_number:>6}  {r.firmware:>8}")
    if not total:
        rates = ", ".join(map(str, bauds))
        raise DxlError(f"no servo answered on {args.port} at {rates} bps for IDs "
                       f"{args.ids.start}-{args.ids.stop - 1} (check power, wiring, baud rate; "
                       f"try --all-bauds)")
    return 0
