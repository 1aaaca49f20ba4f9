"""A compiled kernel kept as native code: compiled once by numba, loaded afterwards without it.

A :func:`.jit.compiled` kernel needs numba in the process that runs it: its import and its
target's set-up cost the emulator's child ~0.4 s of CPU before the first tick, even when the
kernel itself comes from numba's cache. :class:`NativeKernel` instead compiles its function
once as a C-callable ``numba.cfunc`` (no ``fastmath``: the same IEEE operations as the Python
function, so the same bits), keeps the object code numba's code generator made for this CPU in
the kernel cache folder (:data:`.jit.CACHE_DIR`, named for the package's sources), and later
loads that object with llvmlite (numba's LLVM binding, installed with it) into an MCJIT engine,
which costs ~0.05 s. The function is then called through :mod:`ctypes`.

The C signature is ``int64 f(int64 *arrays, scalars...)``: ``arrays`` holds, per array
parameter, its data address and its dimensions; :meth:`NativeKernel.bind` fills it once for
arrays that stay put, and the bound call passes only the scalars. The kernel must allocate
nothing (no ``np.empty``): the arrays are views of the caller's memory.

The cached object is keyed by the kernel's byte code, the compiler (numba's and llvmlite's versions, the interpreter),
the CPU it was compiled for (numba's ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES``, else the
host's name and features as LLVM reports them) and every ``NUMBA_*`` setting, beside the
sources in the folder's name. Its file is written atomically with a checksum
(:class:`swerve.core.value_cache.ValueCache`); a damaged one is compiled again. The object
names the external symbols it needs (the C library's maths, numba's helpers for its error
paths); one that cannot be resolved in this process is not loaded, so a missing symbol is never
left for the loader to meet. Where there is no object to load (not Linux; a numba whose code
library does not give its object code, which is recorded as an empty entry for that numba; an
object this process cannot link) the kernel is numba's own ``njit(cache=True)`` of the same
function, as :mod:`.jit` makes the other kernels.
"""
from __future__ import annotations

import ctypes
import hashlib
import importlib.machinery
import importlib.util
import logging
import marshal
import os
import platform
import struct
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from swerve.core.value_cache import ValueCache

from . import jit

#: The first line of a cached object file (its format: symbol, externals, object code).
LAYOUT = b"swerve native kernel 1\n"
#: Parameter types of :class:`NativeKernel`: scalars and C-contiguous arrays of one or two dimensions.
SCALARS = {"i8": ctypes.c_int64, "f8": ctypes.c_double}
ARRAYS = {"i8[:]": ("i8", 1), "f8[:]": ("f8", 1), "i8[:,:]": ("i8", 2), "f8[:,:]": ("f8", 2)}
_DTYPES = {"i8": np.dtype(np.int64), "f8": np.dtype(np.float64)}
#: Whether objects are kept and loaded here: ELF objects, which :func:`_undefined_symbols` reads (Linux).
OBJECTS_LOADABLE = sys.platform.startswith("linux")

log = logging.getLogger(__name__)

_engines: list = []              # the MCJIT engines of loaded kernels: their code lives as long as they do
_llvm_lock = threading.Lock()
_llvm_ready = False


class NativeLoadError(RuntimeError):
    """No object to keep or load: object code this numba does not give or that is not ELF, or an
    object needing an external symbol this process lacks."""


@dataclass(frozen=True)
class _Object:
    """A compiled kernel as cached: its C entry point's symbol, the external symbols it needs and
    its object code (ELF on Linux)."""
    symbol: str
    externals: tuple[str, ...]
    code: bytes

    def pack(self) -> bytes:
        return b"\n".join((self.symbol.encode(), " ".join(self.externals).encode(), self.code))

    @classmethod
    def unpack(cls, data: bytes) -> "_Object":
        symbol, externals, code = data.split(b"\n", 2)
        return cls(symbol.decode(), tuple(externals.decode().split()), code)


class NativeKernel:
    """``fn`` compiled to native code once, then loaded from the kernel cache without numba.

    Parameters
    ----------
    fn : callable
        The kernel, written for numba's nopython mode; it returns an int and allocates nothing.
    params : sequence of str
        The type of each parameter of ``fn`` in order: ``"i8"``, ``"f8"`` (scalars) or
        ``"i8[:]"``, ``"f8[:]"``, ``"i8[:,:]"``, ``"f8[:,:]"`` (C-contiguous arrays).
    depends : tuple of str
        Source files of the :func:`.jit.jitable` helpers ``fn`` calls (in this package).

    :meth:`load` makes the code ready (the first :meth:`bind` loads it otherwise); :attr:`hit`
    tells whether it came from the cache.
    """

    def __init__(self, fn: Callable, params: tuple[str, ...], depends: tuple[str, ...] = ()):
        jit.check_depends(fn, depends)
        unknown = [p for p in params if p not in SCALARS and p not in ARRAYS]
        if unknown:
            raise ValueError(f"{fn.__name__}: unknown parameter types {unknown}")
        if any(a in ARRAYS and b in SCALARS for a, b in zip(params, params[1:])):
            raise ValueError(f"{fn.__name__}: the scalar parameters must come before the arrays")
        self.py_func = fn
        self.params = tuple(params)
        self._arrays = [ARRAYS[p] for p in params if p in ARRAYS]
        self._cache = ValueCache(jit.CACHE_DIR, f"native-{fn.__name__}", LAYOUT, suffix=".o")
        self._function = None
        self._dispatcher = None
        self._lock = threading.Lock()
        #: Whether the code came from the cached object (else numba compiled it in this process).
        self.hit: bool | None = None

    @property
    def loaded(self) -> bool:
        """Whether the code is ready (:meth:`load` ran)."""
        return self._function is not None or self._dispatcher is not None

    def load(self) -> None:
        """Load the cached object (with llvmlite alone), or compile it with numba and cache it.
        Where there is no object to load (not Linux, a numba whose object code cannot be taken,
        an object this process cannot link) the kernel is numba's own ``njit(cache=True)``."""
        with self._lock:
            if self.loaded:
                return
            address, hit = None, False
            if OBJECTS_LOADABLE:
                fresh: list[int] = []       # the address in numba's engine, when compiled in this process
                data, hit = self._cache.payload(self._key(), lambda: self._object(fresh))
                if fresh:
                    address = fresh[0]
                elif data:
                    try:
                        address = _load(_Object.unpack(data))
                    except (NativeLoadError, ValueError) as exc:
                        log.debug("native %s not loaded: %s", self.py_func.__name__, exc)
            if address is None:
                self._dispatcher, self.hit = jit.Kernel(self.py_func).load(), False
                return
            scalars = [SCALARS[p] for p in self.params if p in SCALARS]
            prototype = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, *scalars)
            self._function, self.hit = prototype(address), hit

    def _object(self, address_out: list[int]) -> bytes:
        """:meth:`_compile`'s object, packed; empty (stored as such, so later starts go straight
        to numba's own kernel) where this numba's object code cannot be taken apart."""
        try:
            return self._compile(address_out).pack()
        except NativeLoadError as exc:
            log.debug("native %s not kept: %s", self.py_func.__name__, exc)
            return b""

    def bind(self, *arrays: np.ndarray) -> Callable[..., int]:
        """The kernel over these arrays (the array parameters, in order): a callable of the scalar
        parameters, in order, returning the kernel's int. The arrays must stay alive and in
        place (not resized or replaced) while the callable is used; bind again otherwise."""
        if len(arrays) != len(self._arrays):
            raise ValueError(f"{self.py_func.__name__}: {len(arrays)} arrays given, {len(self._arrays)} expected")
        words = []
        for k, (a, (dtype, ndim)) in enumerate(zip(arrays, self._arrays)):
            if a.dtype != _DTYPES[dtype] or a.ndim != ndim or not a.flags.c_contiguous:
                raise ValueError(f"{self.py_func.__name__}: array {k} is {a.dtype}{list(a.shape)}, "
                                 f"expected a C-contiguous {dtype} array of {ndim} dimensions")
            words += (a.ctypes.data, *a.shape)
        self.load()
        if self._dispatcher is not None:
            dispatcher = self._dispatcher
            return lambda *scalars: dispatcher(*scalars, *arrays)
        block = np.array(words, np.int64)
        call, address = self._function, block.ctypes.data

        def bound(*scalars) -> int:
            return call(address, *scalars)
        bound.keep = (block, arrays)    # the memory the addresses point into
        return bound

    def _key(self) -> str:
        """The cached object's key (hex): the kernel's code, the compiler, the target CPU and
        numba's settings (the helpers' sources name the folder)."""
        spec = importlib.util.find_spec("numba")
        version = Path(spec.origin).with_name("_version.py")
        parts = [self.py_func.__name__, marshal.dumps(self.py_func.__code__).hex(), ",".join(self.params),
                 sys.version, platform.machine(),
                 version.read_text() if version.exists() else "", *_llvm_target(),
                 *sorted(f"{k}={v}" for k, v in os.environ.items() if k.startswith("NUMBA_") and k != "NUMBA_CACHE_DIR")]
        return hashlib.sha256("\0".join(parts).encode()).hexdigest()[:32]

    def _compile(self, address_out: list[int]) -> _Object:
        """Compile ``fn`` as a cfunc with numba; its address in numba's engine goes into
        ``address_out``, and its object code with the symbols it needs is returned."""
        numba = jit.numba_module()
        from numba import types
        from numba.extending import intrinsic, register_jitable

        def address_as(pointer_type):
            @intrinsic
            def as_pointer(typingctx, word):
                def codegen(context, builder, signature, args):
                    return builder.inttoptr(args[0], context.get_value_type(pointer_type))
                return pointer_type(types.int64), codegen
            return as_pointer

        pointers = {d: types.CPointer(numba.from_dtype(_DTYPES[d])) for d in _DTYPES}
        ns = {"kernel": register_jitable(self.py_func), "carray": numba.carray,
              **{f"as_{d}": address_as(pointers[d]) for d in _DTYPES}}
        names, args, word = [], [], 0
        for k, p in enumerate(self.params):
            if p in SCALARS:
                names.append(f"s{k}")
                args.append(f"s{k}")
            else:
                dtype, ndim = ARRAYS[p]
                shape = ", ".join(f"w[{word + 1 + d}]" for d in range(ndim))
                args.append(f"carray(as_{dtype}(w[{word}]), ({shape},))")
                word += 1 + ndim
        source = (f"def entry(words, {', '.join(names)}):\n"
                  f"    w = carray(words, ({word},))\n"
                  f"    return kernel({', '.join(args)})\n")
        exec(compile(source, f"<native {self.py_func.__name__}>", "exec"), ns)
        scalar_types = [types.int64 if p == "i8" else types.float64 for p in self.params if p in SCALARS]
        cf = numba.cfunc(types.int64(pointers["i8"], *scalar_types), error_model="numpy")(ns["entry"])
        _compiled_here.append(cf)
        address_out.append(cf.address)
        try:                            # numba's code library: not public API, checked here
            library = cf._library
            code = library.codegen._tm.emit_object(library._final_module)
        except AttributeError as exc:
            raise NativeLoadError(f"numba {numba.__version__} does not give its object code: {exc}") from None
        return _Object(cf.native_name, _undefined_symbols(code), code)


def native(fn: Callable, params: tuple[str, ...], depends: tuple[str, ...] = ()) -> NativeKernel | None:
    """``fn`` as a :class:`NativeKernel`, or ``None`` where :func:`.jit.can_compile` says no
    (numba not installed, ``SWERVE_NO_JIT`` set, no writable cache folder)."""
    kernel = NativeKernel(fn, params, depends)
    return kernel if jit.can_compile(fn) else None


_compiled_here: list = []         # cfuncs compiled in this process: numba frees their code with them


def _llvm():
    """llvmlite's binding, with the native target initialised and numba's helper symbols added
    (as numba adds them at its import; :func:`_helper_symbols`)."""
    global _llvm_ready
    import llvmlite.binding as ll
    with _llvm_lock:
        if not _llvm_ready:
            ll.initialize_native_target()
            ll.initialize_native_asmprinter()
            for name, address in _helper_symbols().items():
                ll.add_symbol(name, address)
            _llvm_ready = True
    return ll


def _llvm_target() -> tuple[str, str, str, str]:
    """llvmlite's and LLVM's versions, and the CPU name and features the code is compiled for,
    as numba picks them."""
    import llvmlite
    import llvmlite.binding as ll
    name = os.environ.get("NUMBA_CPU_NAME") or ll.get_host_cpu_name()
    features = os.environ.get("NUMBA_CPU_FEATURES")
    if features is None:
        features = "" if os.environ.get("NUMBA_CPU_NAME") else ll.get_host_cpu_features().flatten()
    return llvmlite.__version__, ".".join(map(str, ll.llvm_version_info)), name, features


def _helper_symbols() -> dict[str, int]:
    """The symbols numba gives its compiled code (``numba.core.base._load_global_helpers`` and
    ``numba.core.runtime.nrt``): its C helpers as ``numba_<name>``, the runtime's as
    ``NRT_<name>``, the built-in exception types as ``PyExc_<name>`` and ``_Py_NoneStruct``.
    The two helper extension modules are loaded from numba's folder by file, without importing
    the numba package."""
    folder = Path(importlib.util.find_spec("numba").origin).parent
    symbols = {"_Py_NoneStruct": id(None)}
    for name, file, prefix in (("numba._helperlib", "_helperlib", "numba_"), ("numba._dynfunc", "_dynfunc", "numba_"),
                               ("numba.core.runtime._nrt_python", "core/runtime/_nrt_python", "NRT_")):
        module = _extension(name, folder / file)
        for key, address in module.c_helpers.items():
            symbols[key if key.startswith("_") else prefix + key] = address
    import builtins
    for obj in vars(builtins).values():
        if isinstance(obj, type) and issubclass(obj, BaseException):
            symbols[f"PyExc_{obj.__name__}"] = id(obj)
    return symbols


def _extension(name: str, stem: Path):
    """The extension module at ``stem`` + this interpreter's suffix, as ``name`` (the one in
    ``sys.modules`` if numba was imported)."""
    if name in sys.modules:
        return sys.modules[name]
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = stem.with_name(stem.name + suffix)
        if path.exists():
            loader = importlib.machinery.ExtensionFileLoader(name, str(path))
            module = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, loader))
            loader.exec_module(module)
            return module
    raise NativeLoadError(f"numba's {stem.name} extension is not in {stem.parent}")


def _load(obj: _Object) -> int:
    """Load ``obj`` into a new MCJIT engine; the address of its entry point."""
    ll = _llvm()
    machine = ll.Target.from_default_triple().create_target_machine()
    engine = ll.create_mcjit_compiler(ll.parse_assembly(""), machine)   # also opens the process's symbols
    missing = [s for s in obj.externals if not ll.address_of_symbol(s)]
    if missing:
        raise NativeLoadError(f"symbols not found in this process: {', '.join(missing)}")
    engine.add_object_file(ll.ObjectFileRef.from_data(obj.code))
    engine.finalize_object()
    address = engine.get_function_address(obj.symbol)
    if not address:
        raise NativeLoadError(f"{obj.symbol} is not in the cached object")
    _engines.append(engine)
    return address


def _undefined_symbols(code: bytes) -> tuple[str, ...]:
    """The undefined symbols of an ELF64 little-endian relocatable object (its ``.symtab``)."""
    if code[:6] != b"\x7fELF\x02\x01":
        raise NativeLoadError("the object code is not ELF64 little-endian")
    shoff, = struct.unpack_from("<Q", code, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", code, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", code, shoff + k * shentsize) for k in range(shnum)]
    names = set()
    for _, kind, _, _, offset, size, link, _, _, entsize in sections:
        if kind != 2:                   # SHT_SYMTAB
            continue
        strings = sections[link][4]
        for at in range(offset, offset + size, entsize):
            name, _, _, shndx = struct.unpack_from("<IBBH", code, at)
            if name and shndx == 0:     # SHN_UNDEF
                end = code.index(b"\0", strings + name)
                names.add(code[strings + name:end].decode())
    return tuple(sorted(names))
