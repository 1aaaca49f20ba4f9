"""The range of an FTDI USB-serial adapter's latency timer (the robot file's
``link.adapter_latency_ms``, the emulator's adapter model, ``--adapter-latency-ms``): whole ms in
1..255 (FTDI AN232B-04 §3.3; Linux commit db9240662a44, which also notes the chip runs the
invalid 0 as 1 ms). A module of its own, without imports, so that the command line can bound the
option before it loads the robot file's reader."""

#: Shortest latency timer, ms.
ADAPTER_LATENCY_MIN_MS = 1
#: Longest latency timer, ms.
ADAPTER_LATENCY_MAX_MS = 255

__all__ = ["ADAPTER_LATENCY_MAX_MS", "ADAPTER_LATENCY_MIN_MS"]
