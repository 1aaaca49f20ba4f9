"""Helpers shared by the benchmark scripts: machine description and BENCHMARKS.md sections."""
from __future__ import annotations

import os
import platform
import re
import struct
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "BENCHMARKS.md"


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (or what platform knows)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def write_section(section: str, text: str, path: Path = BENCHMARKS) -> None:
    """Replace the ``section`` heading's block of ``path`` with ``text`` (append if absent)."""
    old = path.read_text() if path.exists() else "# Benchmarks\n"
    pattern = re.compile(rf"^{re.escape(section)}\n.*?(?=^## |\Z)", re.S | re.M)
    block = text.rstrip("\n") + "\n\n"
    new, n = pattern.subn(lambda _m: block, old, count=1)
    if not n:
        new = old.rstrip("\n") + "\n\n" + block
    path.write_text(new.rstrip("\n") + "\n")


#: Linux PM QoS device: while a process holds it open with a value written, idle CPUs stay in
#: idle states whose exit latency is at most that many us (0: the kernel's polling idle loop).
#: Documentation/power/pm_qos_interface.rst in the kernel tree; rt-tests' cyclictest holds it at 0.
CPU_DMA_LATENCY = "/dev/cpu_dma_latency"


class CpuLatencyRequest:
    """Hold a PM QoS CPU latency request of ``latency_us`` while open (a context manager).

    With 0 an idle CPU polls instead of halting, so a blocked thread wakes without the
    halt exit (on a VM, a trip through the hypervisor). It needs write access to
    :data:`CPU_DMA_LATENCY` (root); :meth:`__enter__` raises ``OSError`` otherwise. The request
    ends when the descriptor closes (also when the process dies).
    """

    def __init__(self, latency_us: int = 0):
        if latency_us < 0:
            raise ValueError(f"latency must be >= 0 us, got {latency_us}")
        self.latency_us = int(latency_us)
        self._fd: int | None = None

    def __enter__(self) -> "CpuLatencyRequest":
        fd = os.open(CPU_DMA_LATENCY, os.O_WRONLY)
        try:
            os.write(fd, struct.pack("i", self.latency_us))
        except OSError:
            os.close(fd)
            raise
        self._fd = fd
        return self

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def check_cpu_latency_request(ap) -> None:
    """End the argparse ``ap`` with a one-line error unless a request can be held (check before
    a long run, not after its first half)."""
    try:
        with CpuLatencyRequest(0):
            pass
    except OSError as exc:
        ap.error(f"--pm-qos: cannot hold a CPU latency request: {exc}")
