"""What every doctor check produces: a :class:`Check` line, gathered in a :class:`DoctorReport`.

Verdict: a ``fail`` makes the report fail (``swerve doctor`` exits 1); ``warn`` and ``pass``
do not (exit 0). A setting that ``swerve run`` writes itself before it moves is a ``pass``
whose detail says what run will set.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

PASS, WARN, FAIL = "pass", "warn", "fail"
#: Exit status of ``swerve doctor``: every check passed or only warned / a check failed.
EXIT_OK, EXIT_FAILED = 0, 1


@dataclass(frozen=True)
class Check:
    """One line of the checklist: ``status`` is pass / warn / fail; ``fix`` the one-line remedy."""

    name: str
    status: str
    detail: str
    fix: str = ""

    def line(self) -> str:
        text = f"[{self.status}] {self.name}: {self.detail}"
        return text + (f"\n       fix: {self.fix}" if self.fix and self.status != PASS else "")


@dataclass
class DoctorReport:
    """All checks, plus what ``fix=True`` changed (``fixed``: one sentence per action)."""

    port: str
    checks: list[Check] = field(default_factory=list)
    fixed: list[str] = field(default_factory=list)
    timing: dict | None = None

    @property
    def ok(self) -> bool:
        """True when no check failed (warnings allowed)."""
        return not self.failed

    @property
    def failed(self) -> list[Check]:
        return [c for c in self.checks if c.status == FAIL]

    @property
    def warnings(self) -> list[Check]:
        return [c for c in self.checks if c.status == WARN]

    @property
    def exit_code(self) -> int:
        """:data:`EXIT_OK` when every check passed or only warned, :data:`EXIT_FAILED` else."""
        return EXIT_OK if self.ok else EXIT_FAILED

    def verdict(self) -> str:
        """The last line ``swerve doctor`` prints."""
        if self.failed:
            return f"{len(self.failed)} check(s) failed: " + ", ".join(c.name for c in self.failed)
        if self.warnings:
            return f"no check failed; {len(self.warnings)} warning(s): " + ", ".join(c.name for c in self.warnings)
        return "all checks pass"

    def as_dict(self) -> dict:
        return {"port": self.port, "ok": self.ok, "exit_code": self.exit_code,
                "checks": [asdict(c) for c in self.checks], "fixed": list(self.fixed), "timing": self.timing}


def ids_text(ids) -> str:
    """``[1, 2, 3]`` -> ``"1,2,3"``."""
    return ",".join(map(str, ids))
