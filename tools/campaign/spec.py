"""The campaign file: its typed form and its one loader.

A campaign is a grid of run settings (trajectories × emulator profiles × gain methods × fault
specs × calibrate-or-not) crossed with ``samples`` robots, each robot's physics parameters
drawn from the distributions the file gives (:mod:`swerve.tools.campaign.draw`). Scenario
``index`` is robot ``index // cells`` in grid cell ``index % cells``, so the same robot drives
every trajectory, calibrated and not (paired comparisons).

Every malformed entry is a :class:`~swerve.core.errors.ConfigError` ``FILE:LINE: KEY: problem``
raised by :func:`load_campaign`, before any scenario starts: unknown keys and parameters,
inverted or non-finite bounds, a sample count outside 1..10^6, a missing trajectory, a fault
spec or parameter value the emulator would refuse.
"""
from __future__ import annotations

import hashlib
import itertools
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import yaml

from swerve.configs import shipped
from swerve.core.errors import ConfigError
from swerve.configs.loader import ConfigWarning, Section, document, parse_yaml_text, read_yaml
from swerve.controller.trajectory import TRAJECTORY_DIR
from swerve.emulator.faults import Faults
from swerve.emulator.physics.params import parse_config
from swerve.emulator.physics.profiles import PROFILES, resolve_emulator_config

#: Largest number of samples (robots) and of scenarios in one campaign.
SAMPLES_MAX = 10**6
#: Gain methods a campaign may name besides a gain schedule file.
GAIN_METHODS = ("riccati", "paper")
#: Distribution kinds.
DISTRIBUTIONS = ("uniform", "normal", "choice")
#: How a parameter is drawn for the four wheels: absent (one scalar), ``each`` (one draw per
#: wheel) or ``same`` (one draw given to every wheel).
WHEEL_MODES = ("each", "same")
#: Wheels of the robot (the order of ``robot.yaml``: front_left, rear_left, rear_right, front_right).
WHEELS = 4
#: Smallest share of a normal distribution that must lie within its bounds (draws outside are redrawn).
NORMAL_INSIDE_MIN = 0.01
#: Folder of the shipped campaigns.
SHIPPED_DIR = "campaigns"


@dataclass(frozen=True)
class Distribution:
    """How one value is drawn: ``kind`` uniform (``low``..``high``), normal (``mean``, ``std``,
    truncated to ``low``..``high`` by redrawing) or choice (one of ``values``, equally likely)."""

    kind: str
    low: float | None = None
    high: float | None = None
    mean: float | None = None
    std: float | None = None
    values: tuple = ()


@dataclass(frozen=True)
class Parameter:
    """A physics value to vary: ``key`` the dotted path into the emulator config
    (``contact.friction_coefficient``), ``dist`` its distribution, ``wheels`` None (a scalar),
    ``"each"`` or ``"same"`` (a list of :data:`WHEELS` values), ``integer`` rounds the draws,
    ``source`` where the distribution comes from (or why it is assumed)."""

    key: str
    dist: Distribution
    wheels: str | None = None
    integer: bool = False
    source: str = ""

    @property
    def columns(self) -> tuple[str, ...]:
        """Its results.csv columns: ``key`` or ``key[0]``..``key[3]``."""
        if self.wheels is None:
            return (self.key,)
        return tuple(f"{self.key}[{w}]" for w in range(WHEELS))


@dataclass(frozen=True)
class Cell:
    """One grid cell: the run settings every robot of the campaign is run with."""

    trajectory: str
    profile: str
    gains: str
    faults: str
    calibrate: bool


@dataclass(frozen=True)
class Campaign:
    """A loaded campaign file.

    ``file`` its path, ``text`` its bytes decoded (what ``fingerprint`` hashes), ``seed`` the
    seed of every draw, ``samples`` robots, ``cells`` the grid (trajectory-major order),
    ``parameters`` the drawn physics values, ``robot`` the robot file every scenario's emulated
    robot is built from, ``calibration_distance_m`` the calibration's straight drive.
    """

    file: Path
    text: str
    name: str
    seed: int
    samples: int
    cells: tuple[Cell, ...]
    parameters: tuple[Parameter, ...]
    robot: Path
    calibration_distance_m: float
    files: dict

    def resolve(self, label: str) -> str:
        """The path a trajectory, profile or gains entry names (``label`` as written in the file;
        names such as ``line`` or ``realistic`` stand for themselves)."""
        return self.files.get(label, label)

    @property
    def scenarios(self) -> int:
        """Number of scenarios: ``samples * len(cells)``."""
        return self.samples * len(self.cells)

    @property
    def fingerprint(self) -> str:
        """SHA-256 of the file's text: a results folder belongs to one campaign file."""
        return hashlib.sha256(self.text.encode("utf-8")).hexdigest()

    def with_samples(self, samples: int) -> "Campaign":
        """The same campaign with another sample count (``--samples``), checked like the file's."""
        import dataclasses

        _check_samples(samples, len(self.cells), f"--samples {samples}")
        return dataclasses.replace(self, samples=samples)

    def cell_of(self, index: int) -> tuple[int, Cell]:
        """``(sample, cell)`` of scenario ``index``."""
        if not 0 <= index < self.scenarios:
            raise ConfigError(f"scenario index {index} is outside 0..{self.scenarios - 1}")
        return index // len(self.cells), self.cells[index % len(self.cells)]

    @property
    def varied(self) -> tuple[str, ...]:
        """The grid axes with more than one value (their columns are worth plotting)."""
        axes = ("trajectory", "profile", "gains", "faults", "calibrate")
        return tuple(a for a in axes if len({getattr(c, a) for c in self.cells}) > 1)


def resolve_campaign_file(name_or_path: str) -> Path:
    """A shipped campaign's file (``smoke``, ``tolerances``) or the path given.

    Raises
    ------
    ConfigError
        If it is neither an existing file nor a shipped campaign's name.
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    cand = shipped(f"{SHIPPED_DIR}/{name_or_path}.yaml")
    if path.suffix == "" and cand.is_file():
        return cand
    names = sorted(p.stem for p in shipped(SHIPPED_DIR).glob("*.yaml"))
    raise ConfigError(f"campaign {name_or_path!r}: no such file and not a shipped campaign "
                      f"({', '.join(names)})")


def load_campaign(name_or_path: str | Path) -> Campaign:
    """Read and check a campaign file (or a shipped campaign's name); see the module doc."""
    path = resolve_campaign_file(str(name_or_path))
    doc = read_yaml(path, what="campaign file")
    return parse_campaign(doc.root(), path, path.read_text(encoding="utf-8"))


def parse_campaign_text(text: str, file: str | Path, base: Path | None = None) -> Campaign:
    """:func:`load_campaign` of a file's ``text`` (``file`` names it; relative paths are
    resolved against ``base``, default the file's folder)."""
    top = parse_yaml_text(text, str(file)).root()
    return parse_campaign(top, Path(file) if base is None else base / Path(file).name, text)


def parse_campaign(top: Section, path: Path, text: str) -> Campaign:
    """Build a :class:`Campaign` from the file's top :class:`~swerve.configs.loader.Section`."""
    base = path.parent
    name = top.string("name", path.stem)
    seed = top.integer("seed", min=0, max=2**63 - 1)
    robot = _file(top, "robot", base, shipped("robot.yaml"))
    files = {}
    trajectories = _strings(top, "trajectories", None)
    for i, t in enumerate(trajectories):
        files[t] = _trajectory(top, i, t, base)
    profiles = _strings(top, "profiles", ["ideal"])
    for i, p in enumerate(profiles):
        files[p] = _profile(top, i, p, base)
    gains = _strings(top, "gains", ["riccati"])
    for i, g in enumerate(gains):
        if g not in GAIN_METHODS:
            files[g] = str(_existing(top, ("gains", i), g, base, "gain schedule"))
    faults = _strings(top, "faults", [""], nonempty=False)
    for i, f in enumerate(faults):
        _check_faults(top, i, f)
    calibrate = _booleans(top, "calibrate")
    cal = top.section("calibration", required=False)
    distance = cal.number("distance_m", 1.0, positive=True, max=100.0)
    cal.check_unknown(strict=True)
    cells = tuple(Cell(*c) for c in itertools.product(trajectories, profiles, gains, faults, calibrate))
    params_sec = top.section("parameters", required=False)
    params = tuple(_parameter(params_sec.section(k), str(k)) for k in params_sec.keys())
    samples = top.integer("samples")
    try:
        _check_samples(samples, len(cells), f"got {samples}")
    except ConfigError as exc:
        top.fail(str(exc), "samples")
    top.check_unknown(strict=True)
    for prof in profiles:
        _check_parameters(params_sec, params, files[prof])
    return Campaign(path, text, name, seed, samples, cells, params, robot, distance, files)


def _check_samples(samples: int, cells: int, what: str) -> None:
    if not 0 < samples <= SAMPLES_MAX or samples * cells > SAMPLES_MAX:
        raise ConfigError(f"{what}: the sample count must be within 1..{SAMPLES_MAX} "
                          f"(and samples x {cells} grid cells too)")


def _strings(top: Section, key: str, default: list | None, nonempty: bool = True) -> list[str]:
    """A non-empty list of strings under ``key`` (a single string is a list of one)."""
    value = top.raw(key) if default is None else top.raw(key, default)
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        top.fail("expected a non-empty list of strings", key)
    lst = Section(top.doc, top.path + (key,), value)
    out = []
    for i, v in enumerate(value):
        if v is None and not nonempty:
            v = ""
        if not isinstance(v, str) or (nonempty and not v.strip()):
            lst.fail("expected a non-empty string" if nonempty else "expected a string", i)
        out.append(v)
    if len(set(out)) != len(out):
        top.fail("lists a value twice", key)
    return out


def _booleans(top: Section, key: str) -> list[bool]:
    value = top.raw(key, [False])
    if isinstance(value, bool):
        value = [value]
    if (not isinstance(value, list) or not value or not all(isinstance(v, bool) for v in value)
            or len(set(value)) != len(value)):
        top.fail("expected true, false or a list of them ([false, true])", key)
    return list(value)


def _existing(top: Section, where: tuple, text: str, base: Path, what: str) -> Path:
    p = Path(text).expanduser()
    p = p if p.is_absolute() else base / p
    if not p.is_file():
        sec = Section(top.doc, top.path + where[:1], top.value.get(where[0]))
        sec.fail(f"{what} {text!r}: no such file", where[1])
    return p.resolve()


def _file(top: Section, key: str, base: Path, default: Path) -> Path:
    if key not in top:
        return default
    return _existing(top, (key, None), top.string(key), base, "file")


def _trajectory(top: Section, i: int, text: str, base: Path) -> str:
    """A trajectory name of the shipped set, or a file resolved against the campaign's folder."""
    if Path(text).suffix.lower() not in (".yaml", ".yml", ".csv"):
        if not (TRAJECTORY_DIR / f"{text}.yaml").is_file():
            names = sorted(f.stem for f in TRAJECTORY_DIR.glob("*.yaml"))
            Section(top.doc, top.path + ("trajectories",), top.value["trajectories"]).fail(
                f"unknown trajectory {text!r}: use one of {', '.join(names)} or a .yaml/.csv file",
                i if isinstance(top.value["trajectories"], list) else None)
        return text
    return str(_existing(top, ("trajectories", i if isinstance(top.value["trajectories"], list) else None),
                         text, base, "trajectory"))


def _profile(top: Section, i: int, text: str, base: Path) -> str:
    if text in PROFILES:
        return text
    where = ("profiles", i if isinstance(top.value.get("profiles"), list) else None)
    return str(_existing(top, where, text, base, "emulator profile (not ideal or realistic)"))


def _check_faults(top: Section, i: int, text: str) -> None:
    try:
        Faults.parse(text or None)
    except ConfigError as exc:
        where = i if isinstance(top.value.get("faults"), list) else None
        Section(top.doc, top.path + ("faults",), top.value.get("faults")).fail(str(exc), where)


def _parameter(sec: Section, key: str) -> Parameter:
    kind = sec.choice("dist", DISTRIBUTIONS)
    wheels = sec.choice("wheels", WHEEL_MODES, None) if sec.raw("wheels", None) is not None else None
    integer = sec.boolean("integer", False)
    source = sec.string("source", "", nonempty=False)
    if kind == "choice":
        value = sec.raw("values")
        if not isinstance(value, list) or not value:
            sec.fail("expected a non-empty list", "values")
        lst = Section(sec.doc, sec.path + ("values",), value)
        for j, v in enumerate(value):
            if isinstance(v, (list, dict)) or v is None:
                lst.fail("expected a number, a string or a boolean", j)
            if isinstance(v, float) and not math.isfinite(v):
                lst.fail(f"expected a finite number, got {v}", j)
        dist = Distribution(kind, values=tuple(value))
    else:
        low, high = sec.number("min"), sec.number("max")
        if not low < high:
            sec.fail(f"the bounds are inverted or empty: min {low:g} must be < max {high:g}", "max")
        if kind == "uniform":
            dist = Distribution(kind, low, high)
        else:
            mean, std = sec.number("mean", min=low, max=high), sec.number("std", positive=True)
            inside = 0.5 * (math.erf((high - mean) / (std * math.sqrt(2.0)))
                            - math.erf((low - mean) / (std * math.sqrt(2.0))))
            if not inside >= NORMAL_INSIDE_MIN:
                sec.fail(f"only {inside:.2g} of the normal lies within min..max (at least "
                         f"{NORMAL_INSIDE_MIN:g} is needed): narrow std or widen the bounds", "std")
            dist = Distribution(kind, low, high, mean, std)
    sec.check_unknown(strict=True)
    return Parameter(key, dist, wheels, integer, source)


def set_dotted(data: dict, key: str, value) -> None:
    """Set ``data[a][b]...`` for ``key`` ``"a.b..."``, creating mappings on the way."""
    *heads, last = key.split(".")
    for h in heads:
        nxt = data.get(h)
        if not isinstance(nxt, dict):
            nxt = data[h] = {}
        data = nxt
    data[last] = value


def profile_data(profile: str) -> dict:
    """The parsed YAML of an emulator profile (a name or a file), to apply drawn values to."""
    return read_yaml(resolve_emulator_config(profile), what="emulator config").data


def _check_parameters(sec: Section, params: tuple[Parameter, ...], profile: str) -> None:
    """Each parameter's extreme values applied to ``profile`` must give a physics config the
    emulator accepts, and its key must be one the emulator reads."""
    for p in params:
        d = p.dist
        extremes = d.values if d.kind == "choice" else (d.low, d.high)
        for x in extremes:
            data = profile_data(profile)
            value = round(x) if p.integer and isinstance(x, float) else x
            set_dotted(data, p.key, value if p.wheels is None else [value] * WHEELS)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", ConfigWarning)
                try:
                    parse_config(document(data, f"emulator profile {profile}"))
                except ConfigError as exc:
                    sec.fail(f"the emulator refuses {value!r}"
                             f"{' on every wheel' if p.wheels else ''}: {exc}", p.key)
            if any(isinstance(w.message, ConfigWarning) for w in caught):
                sec.fail("not a parameter of the emulator config (emulator/physics/params.py, "
                         "configs/emulator-realistic.yaml)", p.key)


def dump_physics(data: dict) -> str:
    """YAML text of a physics config (floats written so they read back bit for bit)."""
    return yaml.safe_dump(data, sort_keys=True, default_flow_style=False)


__all__ = ["Campaign", "Cell", "DISTRIBUTIONS", "Distribution", "GAIN_METHODS", "Parameter", "SAMPLES_MAX",
           "WHEELS", "dump_physics", "load_campaign", "parse_campaign", "parse_campaign_text", "profile_data",
           "resolve_campaign_file", "set_dotted"]
