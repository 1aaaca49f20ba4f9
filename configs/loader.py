"""The one typed YAML loader: every config, model and trajectory file is read through it.

:func:`read_yaml` reads a file as UTF-8 text (a binary or non-UTF-8 file is refused), parses it
with PyYAML's safe loader and remembers the line of every value (from the composed nodes'
``start_mark``). :func:`document` wraps data that is already parsed (no line numbers).
Either gives a :class:`Section`, whose typed accessors check one key each and raise
:class:`~swerve.core.errors.ConfigError` with ``file``, ``key`` (dotted path, list items as
``wheels[2]``) and ``line`` set and the one-line message ``FILE:LINE: KEY: problem``.

Unknown keys are a **warning**, not an error: :meth:`Section.check_unknown` emits a
:class:`ConfigWarning` (``FILE:LINE: KEY: unknown key, ignored``) for every key the parser did
not read, so a file written for a newer version still loads, while a typo is still reported.
A key given twice in one mapping is an error. Numbers must be finite (``.nan`` and ``.inf`` are
refused); bounds are given per key, either inline (``min=``/``max=``) or as a :class:`Bound`
from a table of the file's keys (:meth:`Section.bounded`).
"""
from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from swerve.core.errors import ConfigError

# PyYAML's safe loader, in C (libyaml) where PyYAML was built with it (then ``yaml.CSafeLoader``
# exists; the documented import-or-fall-back): the same nodes and marks, ~10x faster.
try:
    from yaml import CSafeLoader as _SafeLoader
except ImportError:
    from yaml import SafeLoader as _SafeLoader

#: Largest YAML file read, bytes (configs and trajectories are a few kB).
YAML_MAX_BYTES = 16 * 2**20


@dataclass(frozen=True)
class Bound:
    """The accepted values of one number in a config file.

    ``lo``..``hi`` inclusive, in ``unit``; ``integer``: an integer is required; ``allowed``: the
    value must be one of these instead (``lo``/``hi`` then span them); ``step``: a multiple of it;
    ``why``: where the range comes from (shown in the docs, not in errors).
    """

    lo: float
    hi: float
    unit: str = ""
    why: str = ""
    integer: bool = False
    allowed: tuple[float, ...] | None = None
    step: float | None = None

    def describe(self) -> str:
        """The range as text: ``[0.005, 1] m``, ``one of 1, -1``, ``[0, 508] us, a multiple of 2``."""
        unit = f" {self.unit}" if self.unit else ""
        if self.allowed is not None:
            return f"one of {', '.join(_show(v) for v in self.allowed)}{unit}"
        text = f"[{self.lo:g}, {self.hi:g}]{unit}"
        return text + (f", a multiple of {self.step:g}" if self.step else "")


class ConfigWarning(UserWarning):
    """A config file has a key no parser reads (message ``FILE:LINE: KEY: unknown key, ignored``)."""


class _Missing:
    def __repr__(self) -> str:
        return "<required>"


#: Default of a required key.
REQUIRED: Any = _Missing()

_Path = tuple[str | int, ...]


def dotted(path: _Path) -> str:
    """``("wheels", 2, "drive_id")`` -> ``"wheels[2].drive_id"``; ``()`` -> ``"(top level)"``."""
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _message(file: str, line: int | None, key: str | None, problem: str) -> str:
    head = f"{file}:{line}" if line is not None else file
    return f"{head}: {key}: {problem}" if key else f"{head}: {problem}"


def config_error(file: str, line: int | None, key: str | None, problem: str,
                 error: type[ConfigError] = ConfigError) -> ConfigError:
    """A ``error`` with fields set and the message ``FILE:LINE: KEY: problem`` on one line."""
    problem = " ".join(str(problem).split())
    return error(_message(file, line, key, problem), file=file, key=key, line=line)


@dataclass(frozen=True)
class Document:
    """A parsed file: its data, its name for messages and the 1-based line of each value."""

    data: Any
    file: str
    lines: Mapping[_Path, int] = field(default_factory=dict)
    error: type[ConfigError] = ConfigError

    def root(self) -> "Section":
        """The top level, which must be a mapping."""
        top = Section(self, (), self.data)
        if not isinstance(self.data, Mapping):
            got = "an empty document" if self.data is None else type(self.data).__name__
            top.fail(f"expected a mapping at the top level, got {got}")
        return top


def _line_map(node: yaml.Node, path: _Path, out: dict[_Path, int], file: str,
              error: type[ConfigError], seen_nodes: set[int] | None = None) -> None:
    seen_nodes = set() if seen_nodes is None else seen_nodes
    if isinstance(node, (yaml.MappingNode, yaml.SequenceNode)):
        if id(node) in seen_nodes:      # an alias (*name): nested ones grow exponentially
            raise config_error(file, node.start_mark.line + 1, dotted(path) or None,
                               "YAML aliases of lists or mappings (*name) are not accepted here", error)
        seen_nodes.add(id(node))
    out.setdefault(path, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for k, v in node.value:
            key = k.value if isinstance(k, yaml.ScalarNode) else str(k.value)
            if key in seen:     # PyYAML would silently keep the last one
                raise config_error(file, k.start_mark.line + 1, dotted(path + (key,)),
                                   f"duplicate key (first on line {out[path + (key,)]})", error)
            seen.add(key)
            out[path + (key,)] = k.start_mark.line + 1      # a section's line is its key's
            _line_map(v, path + (key,), out, file, error, seen_nodes)
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            _line_map(v, path + (i,), out, file, error, seen_nodes)


def _yaml_problem(exc: yaml.YAMLError) -> tuple[int | None, str]:
    if isinstance(exc, yaml.MarkedYAMLError):    # a scanner, parser or constructor error: where and what
        mark, problem = exc.problem_mark, exc.problem or str(exc)
        return (mark.line + 1 if mark is not None else None), f"not valid YAML: {problem}"
    return None, f"not valid YAML: {exc}"


def parse_yaml_text(text: str, file: str, error: type[ConfigError] = ConfigError) -> Document:
    """Parse YAML ``text`` (named ``file`` in messages), keeping the line of every key.

    A mapping entry's line is the line of its key; a list item's is the item's first line.
    """
    loader = _SafeLoader(text)
    try:
        node = loader.get_single_node()
        data = loader.construct_document(node) if node is not None else None
    except yaml.YAMLError as exc:
        line, problem = _yaml_problem(exc)
        raise config_error(file, line, None, problem, error) from None
    except ValueError as exc:       # an integer of more digits than Python converts
        raise config_error(file, None, None, f"not a usable YAML value: {exc}", error) from None
    finally:
        loader.dispose()
    lines: dict[_Path, int] = {}
    if node is not None:
        _line_map(node, (), lines, file, error)
    else:
        lines[()] = 1
    return Document(data, file, lines, error)


def read_yaml(path: str | Path, error: type[ConfigError] = ConfigError, what: str = "config") -> Document:
    """Read a YAML file; refuses unreadable, binary and non-UTF-8 files with a one-line error.

    ``what`` names the kind of file in the "cannot read" message (e.g. ``"robot config"``).
    """
    path = Path(path)
    file = str(path)
    try:
        if path.exists() and not path.is_dir() and not path.is_file():
            raise error(f"{file}: cannot read {what}: not a regular file (a device or a pipe?)", file=file)
        with path.open("rb") as fh:
            raw = fh.read(YAML_MAX_BYTES + 1)
    except OSError as exc:
        raise error(f"{file}: cannot read {what}: {exc.strerror or exc}", file=file) from None
    if len(raw) > YAML_MAX_BYTES:
        raise config_error(file, None, None, f"larger than {YAML_MAX_BYTES // 2**20} MiB: not a config file", error)
    if b"\x00" in raw:
        raise config_error(file, None, None, "binary file (contains NUL bytes), expected YAML text", error)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise config_error(file, line, None, f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset "
                           f"{exc.start})", error) from None
    return parse_yaml_text(text, file, error)


def document(data: Any, file: str = "config", error: type[ConfigError] = ConfigError) -> Document:
    """Wrap already-parsed data (no line numbers) for the same typed access."""
    return Document(data, file, {}, error)


def _kind(value: Any) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, str):
        short = value if len(value) <= 40 else value[:37] + "..."
        return f"the string {short!r}"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return repr(value)


def _looks_numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class Section:
    """Typed access to one mapping (or list) inside a :class:`Document`.

    Accessors take a key and return the checked value; every failure raises the document's
    error class with the key's dotted path and line. Keys read are remembered for
    :meth:`check_unknown`.
    """

    def __init__(self, doc: Document, path: _Path, value: Any):
        self.doc, self.path, self.value = doc, path, value
        self._read: set[Any] = set()

    # -- errors --------------------------------------------------------------------------
    def line(self, key: str | int | None = None) -> int | None:
        """Line of ``key``'s value (or of this section when absent or ``None``)."""
        lines = self.doc.lines
        path = self.path if key is None else self.path + (key,)
        while path not in lines and path:
            path = path[:-1]
        return lines.get(path)

    def key(self, key: str | int | None = None) -> str:
        """Dotted path of ``key`` in this section."""
        return dotted(self.path if key is None else self.path + (key,))

    def error(self, key: str | int | None, problem: str) -> ConfigError:
        """The error for ``key`` (``None``: this section) with file, key and line set."""
        return config_error(self.doc.file, self.line(key), self.key(key), problem, self.doc.error)

    def fail(self, problem: str, key: str | int | None = None):
        """Raise :meth:`error`."""
        raise self.error(key, problem)

    # -- structure -----------------------------------------------------------------------
    def __contains__(self, key: object) -> bool:
        return isinstance(self.value, Mapping) and key in self.value

    def keys(self) -> list[str]:
        """The mapping's keys (marks them read)."""
        self._mapping()
        self._read.update(self.value)
        return list(self.value)

    def _mapping(self) -> Mapping:
        if not isinstance(self.value, Mapping):
            self.fail(f"expected a mapping, got {_kind(self.value)}")
        return self.value

    def raw(self, key: str, default: Any = REQUIRED) -> Any:
        """The value of ``key`` unchecked (``default`` if absent; required if no default)."""
        m = self._mapping()
        self._read.add(key)
        if key not in m or m[key] is None:
            if default is REQUIRED:
                self.fail("missing" if key not in m else "missing (the value is null)", key)
            return default
        return m[key]

    def section(self, key: str, required: bool = True) -> "Section":
        """The mapping under ``key``; an absent or empty optional section reads as ``{}``."""
        value = self.raw(key, REQUIRED if required else None)
        if value is None:
            return Section(self.doc, self.path + (key,), {})
        sub = Section(self.doc, self.path + (key,), value)
        sub._mapping()
        return sub

    def item(self, index: int) -> "Section":
        """Element ``index`` of this list as a section."""
        return Section(self.doc, self.path + (index,), self.value[index])

    def items(self, key: str, length: int | None = None) -> list["Section"]:
        """The list under ``key`` as one :class:`Section` per element (``length`` checked)."""
        value = self.raw(key)
        if not isinstance(value, list) or (length is not None and len(value) != length):
            want = f"a list of exactly {length} items" if length is not None else "a list"
            got = _kind(value) if not isinstance(value, list) else f"{len(value)} items"
            self.fail(f"expected {want}, got {got}", key)
        lst = Section(self.doc, self.path + (key,), value)
        return [lst.item(i) for i in range(len(value))]

    def unread(self) -> dict:
        """The entries of this mapping that no accessor has read (marks them read)."""
        if not isinstance(self.value, Mapping):
            return {}
        out = {k: v for k, v in self.value.items() if k not in self._read}
        self._read.update(out)
        return out

    def check_unknown(self, strict: bool = False) -> None:
        """Report keys nobody read: a :class:`ConfigWarning` each (``strict``: an error)."""
        if not isinstance(self.value, Mapping):
            return
        for k in self.value:
            if k not in self._read:
                if strict:
                    self.fail("unknown key", k)
                warnings.warn(_message(self.doc.file, self.line(k), self.key(k), "unknown key, ignored"),
                              ConfigWarning, stacklevel=2)

    # -- scalars ---------------------------------------------------------------------------
    def _number_value(self, value: Any, key: str | int, *, positive: bool, nonneg: bool,
                      min: float | None, max: float | None) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            hint = ""
            if isinstance(value, str) and _looks_numeric(value):
                hint = " (YAML reads an exponent without a dot as text: write e.g. 1.0e-3)"
            self.fail(f"expected a number, got {_kind(value)}{hint}", key)
        try:
            x = float(value)
        except OverflowError:
            self.fail(f"{value} is too large", key)
        if not math.isfinite(x):
            self.fail(f"expected a finite number, got {value}", key)
        if positive and x <= 0:
            self.fail(f"must be > 0, got {value}", key)
        if nonneg and x < 0:
            self.fail(f"must be >= 0, got {value}", key)
        if nonneg and min is None:
            min = 0.0
        if (min is not None and x < min) or (max is not None and x > max):
            self.fail(f"{value:g} is outside [{_bound(min, '-inf')}, {_bound(max, 'inf')}]", key)
        return x

    def number(self, key: str, default: Any = REQUIRED, *, positive: bool = False, nonneg: bool = False,
               min: float | None = None, max: float | None = None) -> float:
        """A finite number (float); ``positive`` (> 0), ``nonneg`` (>= 0), ``min``..``max``."""
        value = self.raw(key, default)
        if value is None:
            return None
        return self._number_value(value, key, positive=positive, nonneg=nonneg, min=min, max=max)

    def integer(self, key: str | int, default: Any = REQUIRED, *, min: int | None = None,
                max: int | None = None) -> int:
        """An integer (a float such as ``3.0`` is refused) within ``min``..``max``."""
        value = self.value[key] if isinstance(key, int) else self.raw(key, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(f"expected an integer, got {_kind(value)}", key)
        if (min is not None and value < min) or (max is not None and value > max):
            self.fail(f"{value} is outside [{_bound(min, '-inf')}, {_bound(max, 'inf')}]", key)
        return value

    def bounded(self, key: str | int, bound: Bound, default: Any = REQUIRED) -> float | int:
        """A number within ``bound`` (an int when ``bound.integer``); ``default`` when absent.

        Every failure names the accepted range: ``FILE:LINE: KEY: 1e-300 is outside [0.005, 1] m``.
        """
        if bound.integer:
            value = self.integer(key, default)
        else:
            value = self.value[key] if isinstance(key, int) else self.raw(key, default)
            if value is not None:
                value = self._number_value(value, key, positive=False, nonneg=False, min=None, max=None)
        if value is None:
            return None
        if bound.allowed is not None:
            if value not in bound.allowed:
                self.fail(f"expected {bound.describe()}, got {_show(value)}", key)
        elif not bound.lo <= value <= bound.hi or (bound.step and value % bound.step):
            self.fail(f"{_show(value)} is outside {bound.describe()}", key)
        return value

    def bounded_list(self, key: str, length: int, bound: Bound) -> tuple:
        """A list of ``length`` numbers, each within ``bound``."""
        lst = self._list(key, length, REQUIRED, "integers" if bound.integer else "numbers")
        return tuple(lst.bounded(i, bound) for i in range(len(lst.value)))

    def boolean(self, key: str, default: Any = REQUIRED) -> bool:
        """``true`` or ``false``."""
        value = self.raw(key, default)
        if not isinstance(value, bool):
            self.fail(f"expected true or false, got {_kind(value)}", key)
        return value

    def string(self, key: str, default: Any = REQUIRED, *, nonempty: bool = True) -> str:
        """A string (``nonempty``: not ``""``)."""
        value = self.raw(key, default)
        if value is None:
            return None
        if not isinstance(value, str) or (nonempty and not value.strip()):
            self.fail(f"expected a {'non-empty ' if nonempty else ''}string, got {_kind(value)}", key)
        return value

    def choice(self, key: str, choices: Sequence[Any] | Mapping[str, Any], default: Any = REQUIRED) -> Any:
        """One of ``choices``; for a mapping, the value the chosen name maps to."""
        value = self.raw(key, default)
        names = list(choices)
        if isinstance(value, (list, dict)) or value not in names or isinstance(value, bool):
            self.fail(f"expected one of {', '.join(map(str, names))}; got {_kind(value)}", key)
        return choices[value] if isinstance(choices, Mapping) else value

    def _list(self, key: str, length: int | None, default: Any, what: str) -> "Section | None":
        """The list under ``key`` (``length`` checked) as a section, or ``None`` if absent."""
        value = self.raw(key, default)
        if value is None:
            return None
        value = list(value) if isinstance(value, tuple) else value
        if not isinstance(value, list) or (length is not None and len(value) != length):
            want = f"a list of {length} {what}" if length is not None else f"a list of {what}"
            self.fail(f"expected {want}, got {_kind(value) if not isinstance(value, list) else value}", key)
        return Section(self.doc, self.path + (key,), value)

    def numbers(self, key: str, length: int | None = None, default: Any = REQUIRED, *,
                positive: bool = False, nonneg: bool = False, min: float | None = None,
                max: float | None = None) -> tuple[float, ...] | None:
        """A list of finite numbers (``length`` checked), each bounded like :meth:`number`."""
        lst = self._list(key, length, default, "numbers")
        if lst is None:
            return None
        return tuple(lst._number_value(v, i, positive=positive, nonneg=nonneg, min=min, max=max)
                     for i, v in enumerate(lst.value))

    def integers(self, key: str, length: int | None = None, default: Any = REQUIRED, *,
                 min: int | None = None, max: int | None = None,
                 allowed: Sequence[int] | None = None) -> tuple[int, ...] | None:
        """A list of integers (``length`` checked), each in ``min``..``max`` or in ``allowed``."""
        lst = self._list(key, length, default, "integers")
        if lst is None:
            return None
        out = tuple(lst.integer(i, min=min, max=max) for i in range(len(lst.value)))
        if allowed is not None:
            for i, v in enumerate(out):
                if v not in allowed:
                    lst.fail(f"expected one of {', '.join(map(str, allowed))}, got {v}", i)
        return out


def _show(value: float | int) -> str:
    """A number for a message: ``%g`` for floats, digits for ints (shortened past 20)."""
    if isinstance(value, int):
        text = str(value) if abs(value) < 10**20 else f"{str(value)[:8]}...({len(str(abs(value)))} digits)"
        return text
    return f"{value:g}"


def _bound(b: float | None, none: str) -> str:
    return none if b is None else f"{b:g}"


__all__ = ["Bound", "ConfigWarning", "Document", "REQUIRED", "Section", "config_error", "document", "dotted",
           "parse_yaml_text", "read_yaml"]
