"""The one place where numba flags are set, and where compiled kernels are kept.

``cache=True`` keeps compiled kernels on disk so a second process pays no
compile time. numba keys a cached kernel on its own source file only, so an
edit to a kernel it calls in another module would leave a stale kernel in the
cache; hence this package's kernels are cached in a directory named after a
hash of the modules whose kernels other kernels call (``sim/``, ``render/``,
``metrics.py``, ``envs/grippers.py``): ``~/.cache/cloth_gym/numba/<hash>``, under ``$XDG_CACHE_HOME``
if set, or ``$NUMBA_CACHE_DIR/cloth_gym/<hash>`` when the user sets
``NUMBA_CACHE_DIR``. The directory is chosen by a cache locator that answers for
this package's files only: no environment variable and no numba setting of the
process is changed. The locator plugs into numba's caching internals; should a
numba release change them, the kernels fall back to numba's own cache locations
(with a warning) and still run. ``make clean-cache`` removes the cache.

The first kernel that compiles in a process prints one line to stderr (a cold
first step takes half a minute or more and would otherwise look like a hang);
:func:`cloth_gym.warmup` compiles everything ahead of time.

``error_model="numpy"`` turns a division by zero into inf/NaN (caught by the
divergence check) instead of an exception inside a kernel; ``fastmath`` stays
off so results are reproducible and finite-difference tests are meaningful.
"""

from __future__ import annotations

import hashlib
import os
import sys
import warnings
from pathlib import Path

import numba
from llvmlite import ir as _ir
from numba import types as _types
from numba.core import caching as _caching
from numba.core import cgutils as _cgutils
from numba.core import codegen as _codegen
from numba.core import dispatcher as _dispatcher
from numba.core import errors as _errors
from numba.core import event as _event
from numba.core.extending import intrinsic as _intrinsic
from numba.core.registry import CPUDispatcher
from numba.experimental import structref as _structref

_PACKAGE = Path(__file__).resolve().parents[1]

COMPILE_NOTICE = "cloth_gym: compiling simulator kernels, under a minute, once (cached in {path})"


def _kernel_sources_hash() -> str:
    h = hashlib.sha1()
    for p in sorted([*_PACKAGE.glob("sim/**/*.py"), *_PACKAGE.glob("render/*.py"), _PACKAGE / "metrics.py",
                    _PACKAGE / "envs" / "grippers.py"]):
        if p.is_file():
            h.update(p.name.encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def cache_dir() -> Path:
    """Where this package's compiled kernels are cached (see the module docstring)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "cloth_gym" / _kernel_sources_hash()
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "cloth_gym" / "numba" / _kernel_sources_hash()


_CACHE_DIR = cache_dir()


def _is_package_file(py_file: str) -> bool:
    try:
        return Path(py_file).resolve().is_relative_to(_PACKAGE)
    except (OSError, ValueError):
        return False


def _install_locator() -> bool:
    """Put :class:`_PackageCacheLocator` first among numba's cache locators; False (and a
    warning) if this numba's caching internals differ from those it was written against."""
    try:
        base = (_caching._SourceFileBackedLocatorMixin, _caching._CacheLocator)
        impl = getattr(_caching, "CacheImpl", None) or _caching._CacheImpl
        locators = impl._locator_classes
    except AttributeError as err:
        warnings.warn(f"cloth_gym: numba {numba.__version__} has no cache locator hook ({err}); kernels are "
                      "cached where numba puts them by default", RuntimeWarning, stacklevel=2)
        return False

    class _PackageCacheLocator(*base):
        """numba cache locator for this package's kernels: ``cache_dir()/<source folder>``."""

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(str(_CACHE_DIR), self.get_suitable_cache_subpath(py_file))

        def get_cache_path(self):
            return self._cache_path

        @classmethod
        def from_function(cls, py_func, py_file):
            if not _is_package_file(py_file):
                return None  # not ours: numba's own locators decide
            return super().from_function(py_func, py_file)

    if not any(c.__name__ == "_PackageCacheLocator" for c in locators):
        locators.insert(0, _PackageCacheLocator)
    return True


LOCATOR_INSTALLED = _install_locator()
"""Whether this package's kernels are cached in :func:`cache_dir` (else numba's default places)."""


class _CompileNotice(_event.Listener):
    """Prints :data:`COMPILE_NOTICE` once per process, when a kernel of this package first compiles."""

    printed = False

    def on_start(self, event):
        if _CompileNotice.printed:
            return
        dispatcher = (event.data or {}).get("dispatcher")
        module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
        if module.split(".")[0] == "cloth_gym":
            _CompileNotice.printed = True
            where = _CACHE_DIR if LOCATOR_INSTALLED else "numba's default cache"
            print(COMPILE_NOTICE.format(path=where), file=sys.stderr, flush=True)

    def on_end(self, event):
        pass


_event.register("numba:compile", _CompileNotice())

NJIT_FLAGS = dict(cache=True, nogil=True, fastmath=False, error_model="numpy", no_cfunc_wrapper=True)
#: the same for the kernels that only compiled code calls (:func:`kernel_only`, :func:`chosen_by_type`):
#: no Python wrapper (nor a cache of their own: their callers' cache holds them)
KERNEL_ONLY_FLAGS = {**{k: v for k, v in NJIT_FLAGS.items() if k != "cache"}, "no_cpython_wrapper": True}


def njit(fn=None, **overrides):
    """``numba.njit`` with the project's flags (usable bare or with overrides)."""
    flags = {**NJIT_FLAGS, **overrides}
    if fn is None:
        return lambda f: numba.njit(**flags)(f)
    return numba.njit(**flags)(fn)


def njit_brief(fn):
    """:func:`njit` for a kernel that Python calls for microseconds on every env step (a check, a
    lookup): it keeps the interpreter lock. In a batch stepping cloths on several threads, each
    release of the lock lets another thread's Python run, which the releasing thread then waits out
    before its own next line; the implicit step, milliseconds long, is where the lock is released."""
    return njit(fn, nogil=False)


#: The ``module.qualname`` of each :func:`kernel_only` kernel that Python code called in this process
#: (each one then compiled an ordinary njit kernel as well). The package calls only its entry points from
#: Python; the tests check that a first env step leaves this empty.
CALLED_FROM_PYTHON: set[str] = set()


class _LinkOnlyEntry:
    """Stands in for a kernel_only kernel's entry point, which it does not have: the key under which
    compiled callers find the kernel's code."""

    def __init__(self, name):
        self.name = name

    def __repr__(self):
        return f"<kernel_only {self.name}>"


#: Does this numba have the internals the link-only compile plugs into? Without them (a numba release
#: that changed them) kernel_only kernels compile their machine code as numba does by default.
_LINK_ONLY = all(
    hasattr(_codegen.CPUCodeLibrary, name)
    for name in ("_finalize_final_module", "_optimize_final_module", "_finalize_dynamic_globals",
                 "_verify_declare_only_symbols"))


class _KernelCompiler(_dispatcher._FunctionCompiler):
    """numba's function compiler for :func:`kernel_only` and :func:`chosen_by_type` kernels: it
    compiles as far as the LLVM IR the callers link, no further (numba's ``no_compile`` flag skips
    the kernel's own entry point, and with it the machine code for it); for a kernel chosen by type
    it compiles the function its chooser returns for the argument types."""

    chooses = False

    def _customize_flags(self, flags):
        flags.no_compile = _LINK_ONLY
        return flags

    def _get_implementation(self, args, kws):
        if not self.chooses:
            return self.py_func
        impl = self.py_func(*args, **kws)
        if impl is None:
            raise _errors.TypingError(f"{self.py_func.__name__}: no implementation for the types {args}")
        return impl


def _finalize_for_linking(library):
    """numba's ``CodeLibrary._finalize_final_module`` without the two steps that hand the module to
    the JIT engine and emit its machine code: a kernel_only kernel's module is only ever linked into
    its callers' modules, whose own optimisation and code emission cover it."""
    library._finalize_dynamic_globals()
    library._verify_declare_only_symbols()
    library._finalized = True


class _KernelOnly(CPUDispatcher):
    """A numba dispatcher whose kernels compiled code calls directly: no CPython wrapper, no module
    optimisation and no machine code of their own (each caller links the kernel's LLVM IR into its
    module, optimises and emits it there). A call from Python compiles and runs an ordinary
    ``njit`` kernel of the same function. See :func:`kernel_only`."""

    def __init__(self, py_func, locals, targetoptions):
        super().__init__(py_func=py_func, locals=locals, targetoptions=targetoptions)
        self._compiler = _KernelCompiler(py_func, self.targetdescr, targetoptions, locals,
                                         self._compiler.pipeline_class)

    def add_overload(self, cres):
        """Record a compiled signature for compiled callers: its library is finalised for linking only
        (no module optimisation, no machine code), a token takes the place of the entry point, and
        the target context learns that a call to it lowers to the kernel's code."""
        if not _LINK_ONLY:
            return super().add_overload(cres)
        library = cres.library
        library._finalize_final_module = lambda: _finalize_for_linking(library)
        library._optimize_final_module = lambda: None
        token = _LinkOnlyEntry(cres.fndesc.qualname)
        self.targetctx.insert_user_function(token, cres.fndesc, [library])
        self.overloads[tuple(cres.signature.args)] = cres._replace(entry_point=token)

    def __call__(self, *args, **kwargs):
        python_kernel = getattr(self, "_python_kernel", None)
        if python_kernel is None:
            CALLED_FROM_PYTHON.add(f"{self.py_func.__module__}.{self.py_func.__qualname__}")
            python_kernel = self._python_kernel = njit(self.py_func)
        return python_kernel(*args, **kwargs)


def kernel_only(fn):
    """``fn`` as a kernel for compiled callers (with :data:`KERNEL_ONLY_FLAGS`), without three things
    numba builds for every signature of an ``njit`` kernel that only Python calls need:

    * the CPython wrapper, which converts each argument from a Python object; for a kernel taking
      the solver's bundles (dozens of arrays) it cost about 0.7 CPU s of compile, for a plain one a
      few hundredths, and a step calls about a hundred kernels;
    * machine code of its own: numba emits one for each kernel with its callees linked in, so every
      layer of a call tree emits the layers below it again (about 1.8 of CornerLift's first-step
      compile seconds). The kernel's code lives in its callers' modules, and in their cache;
    * a module-wide optimisation of its own: numba optimises each kernel's module, callees linked
      in, and then its callers' modules with it again; a kernel_only kernel's code (optimised
      function by function) is optimised with the whole module of the kernel Python calls, once
      (about 1.8 s of LLVM passes for CornerLift; the step's speed and results are the same).

    Called from Python (tests, a user's script), it compiles an ordinary ``njit`` kernel of ``fn``
    on its first call (cached on disk like any kernel), runs it, and records the kernel's name in
    :data:`CALLED_FROM_PYTHON`."""
    return _KernelOnly(py_func=fn, locals={}, targetoptions={**KERNEL_ONLY_FLAGS, "nopython": True})


class _ChosenByType(_KernelOnly):
    """A :func:`kernel_only` dispatcher whose code its chooser picks by the argument types; Python
    cannot call it (see :func:`chosen_by_type`)."""

    def __init__(self, py_func, locals, targetoptions):
        super().__init__(py_func=py_func, locals=locals, targetoptions=targetoptions)
        self._compiler.chooses = True

    def __call__(self, *args, **kwargs):
        raise NotImplementedError(f"{self.py_func.__name__}: chosen by type in compiled code; callable from "
                                  "compiled kernels only")


def chosen_by_type(choose):
    """A kernel for compiled callers whose code depends on the numba types of its arguments, as
    ``numba.extending.overload`` makes one, compiled like a :func:`kernel_only` kernel (no CPython
    wrapper, module optimisation or machine code of its own). ``choose`` takes the kernel's
    arguments as numba types, while numba types a caller, and returns the Python function to compile
    for them (the same parameters), or None (a typing error). The step uses it to compile only the code of the
    preconditioner family, collision pass, Newton passes and strain limiter it runs: an overload's
    body would emit machine code of its own, with every kernel it calls linked in."""
    return _ChosenByType(py_func=choose, locals={}, targetoptions={**KERNEL_ONLY_FLAGS, "nopython": True})


@njit
def copy_into(dst, src):
    """``dst[...] = src`` for 1-D or 2-D arrays of the same shape, element by element (another shape
    is a ValueError). numba's own array assignment checks the shapes with an error message built
    from them, which compiles numba's whole string formatting (about 3 CPU s) into the first
    kernel that assigns one array to another; this one does not."""
    if dst.shape != src.shape:
        raise ValueError("copy_into: the arrays differ in shape")
    if src.ndim == 1:
        for i in range(src.shape[0]):
            dst[i] = src[i]
    else:
        for i in range(src.shape[0]):
            for k in range(src.shape[1]):
                dst[i, k] = src[i, k]


@njit
def runtime(flag):
    """``flag`` as a run-time value. numba compiles a kernel once for each literal it is called with, so
    a large kernel called with ``True`` at one site and ``False`` at another is compiled twice (the
    implicit solver's setup and force evaluation were); ``kernel(..., runtime(False))`` compiles it
    once, the branch taken at run time. (``bool()`` makes the value plain: returning ``flag`` itself
    would hand its literal type on.)"""
    return bool(flag)


@_intrinsic
def cycles(typingctx):
    """The CPU's cycle counter (``llvm.readcyclecounter``: the time-stamp counter on x86, the
    virtual counter on ARM64, 0 where the target has none), for the solver's phase profile
    (:class:`~cloth_gym.sim.bundles.Phase`). A tick count only: the Python side converts ticks to
    seconds by the counter's rate, measured once per process
    (:func:`~cloth_gym.sim.solver.cycles_per_second`)."""
    def codegen(context, builder, signature, args):
        fn = _cgutils.get_or_insert_function(builder.module, _ir.FunctionType(_ir.IntType(64), []),
                                             "llvm.readcyclecounter")
        return builder.call(fn, [])

    return _types.int64(), codegen


@_structref.register
class BundleRef(_types.StructRef):
    """The numba type of a bundle passed by reference (:func:`by_ref`): one class for every
    bundle, told apart by its fields and their types."""

    def preprocess_fields(self, fields):
        return tuple((name, _types.unliteral(t)) for name, t in fields)


@_intrinsic
def by_ref(typingctx, bundle):
    """``bundle`` (a NamedTuple of arrays and scalars) as a :class:`BundleRef`, a struct on the heap
    holding the same fields (the same arrays, not copies), read the same way (``ref.name``).
    Compiled code only.

    numba passes a NamedTuple by value, as one argument per array field (data pointer, shape,
    strides, ...), and counts references to each of its arrays wherever the bundle is passed,
    assigned or dropped; in the implicit step, which hands the solver's bundles of dozens of arrays
    to every stage, that made most of the code LLVM had to optimise. A BundleRef is one pointer
    and one reference count (docs/cli.md, "Where the first run's CPU goes")."""
    if not isinstance(bundle, _types.BaseNamedTuple):
        return None
    ref_type = BundleRef(list(zip(bundle.fields, bundle.types)))

    def codegen(context, builder, signature, args):
        from numba.experimental.jitclass.base import imp_dtor

        [value] = args
        payload = context.data_model_manager[ref_type.get_data_type()].get_value_type()
        meminfo = context.nrt.meminfo_alloc_dtor(
            builder, context.get_constant(_types.uintp, context.get_abi_sizeof(payload)),
            imp_dtor(context, builder.module, ref_type))  # the destructor drops each field's reference
        ref = context.make_helper(builder, ref_type)
        ref.meminfo = meminfo
        data = _structref._Utils(context, builder, ref_type).get_data_struct(ref._getvalue())
        for i, name in enumerate(bundle.fields):
            setattr(data, name, builder.extract_value(value, i))
        context.nrt.incref(builder, bundle, value)  # the struct holds a reference to each array
        return ref._getvalue()

    return ref_type(bundle), codegen
