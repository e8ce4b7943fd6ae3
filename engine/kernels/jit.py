"""Compilation options shared by the kernels.

``JIT`` is for kernels the host (or another kernel) calls: cached on disk,
GIL released, numpy error model (no Python exceptions in the pair loop).
Fast-math is limited to contraction (FMA) and reciprocal approximation: no
``nnan``/``ninf``, so comparisons stay IEEE-correct for degenerate input.

``EXACT_JIT`` is ``JIT`` without fast-math, for arithmetic whose bits must not depend
on the caller (poses, rigid moves): such a kernel is called, never inlined at Numba-IR
level, so LLVM keeps its instructions free of contraction wherever it lands.

``BORROW`` is for small helpers that read or write the caller's arrays inside a branchy
loop (a traversal's unfolding, a record of a result, a heap): compiled apart without
reference counting (``_nrt=False``: they can allocate nothing) and inlined by LLVM. A
helper that takes arrays and is spliced in by ``INLINE`` instead gets an atomic incref and
decref of each array on every call wherever the loop branches: measured, a result record
cost 42 ns that way and 9.5 ns as ``BORROW``, and the reference counts were 45 % of a
traversal's time. ``EXACT_BORROW`` is the same for ``EXACT_JIT`` helpers.

``INLINE`` is for per-pair helpers. Numba calls another compiled function
through a symbol LLVM does not inline at that stage, and a call inside the pair
loop stops the loop from vectorising; ``inline="always"`` splices the helper in
at Numba-IR level instead. That costs compile time that grows quickly with
nested call sites, so helpers are flat scalar code and every heavy body is
inlined into exactly one loop kernel.

LLVM vectorises a pair loop only after proving (with runtime checks) that its
stores do not overlap its ~44 input rows; its default limits on such checks
(8 and 100) are far below that, so they are raised here, process-wide, before
anything is compiled. The checks run once per loop, not per pair, but they are
hundreds of comparisons (each row of a 2-D array is its own pointer range), and
LLVM runs a block of fewer than its vector step scalar: measured, the iterative
kernel on 16 pairs took 963 ns (60 ns a pair) and on 32 pairs 1,092 ns.
``DISTINCT`` is ``BORROW`` for block kernels whose array arguments never share
memory that the kernel writes (every caller passes separate buffers, or disjoint
rows of one): their pointers are marked ``noalias`` (Numba's ``noalias`` flag,
which no decorator option sets, so :data:`NOALIAS` maps ``_noalias`` to it), LLVM
vectorises without checks, and 16 pairs take 162 ns, 32 pairs 284 ns. Where this
Numba cannot take the option, ``DISTINCT`` is plain ``BORROW``. The gathers stay
``BORROW``: marked ``noalias`` they were vectorised with gather instructions, and a list
of 1,296 pairs took 7 % longer.

LLVM runs the pairs past the last full vector of a loop one at a time (its scalar
remainder), so a block of 2 to 7 pairs on AVX-512 float64 is 2 to 7 scalar iterations:
the iterative kernel took 141 ns on 2 pairs and 243 ns on 4, against 114 ns on 8. The
block kernels that often see such blocks (the paired kernels of the traversal's levels
and of ``mesh_distance``'s refinements, and ``child_bounds``) are :func:`tail_masked`:
LLVM folds the remainder into masked vector lanes (its ``prefer-predicate-over-epilogue``
option, set only while such a kernel is optimised), and 1 to 8 pairs take one vector
iteration (111 ns). Long loops pay for the masks (the cull on 256 pairs: 545 → 620 ns), so
the row kernels stay unmasked (``benchmarks/block_kernels.py``; BENCHMARKS.md, issue 15,
eleventh step).

:func:`stack_buffer` gives a kernel buffers in its own stack frame (no allocation,
release or atomic reference counts), for fixed-size working arrays that never leave it.

Numba's on-disk cache is keyed on the timestamp of the file that defines a
kernel, but these kernels inline helpers from sibling files: an edit there
would leave stale machine code in use. The cache directory therefore carries
a hash of the whole ``engine/kernels`` source, every sub-folder included (``$NUMBA_CACHE_DIR``, else
``~/.cache/mrdem/numba``, then ``kernels-<hash>``).
"""

import hashlib
import os
from pathlib import Path

import llvmlite.binding as llvm
import numba
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


def source_hash(root: Path) -> str:
    """16 hex digits of SHA-256 over every ``*.py`` below ``root`` (sub-folders included:
    helpers inline across them), each file's relative path and bytes, in path order."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


KERNEL_SOURCE_HASH = source_hash(Path(__file__).parent)
_cache_base = numba.config.CACHE_DIR or os.path.join(
    os.path.expanduser("~"), ".cache", "mrdem", "numba"
)
numba.config.CACHE_DIR = os.path.join(_cache_base, f"kernels-{KERNEL_SOURCE_HASH}")

llvm.set_option("mrdem", "--runtime-memory-check-threshold=4096")
llvm.set_option("mrdem", "--memory-check-merge-threshold=4096")
llvm.set_option("mrdem", "--vectorize-memory-check-threshold=4096")

HOST_AVX512 = bool(llvm.get_host_cpu_features().get("avx512f", False))
"""The host has AVX-512 (the kernels are compiled for it): a few block sizes are tuned per
vector width. Numba's cache is keyed on the CPU, so each machine compiles its own."""

JIT = {"cache": True, "nogil": True, "error_model": "numpy", "fastmath": {"contract", "arcp"}}
EXACT_JIT = {**JIT, "fastmath": False}
INLINE = {**JIT, "inline": "always"}
BORROW = {**JIT, "_nrt": False}
EXACT_BORROW = {**EXACT_JIT, "_nrt": False}


def _noalias_option() -> dict:
    """``{"_noalias": True}`` once Numba's CPU target maps that option to its ``noalias``
    flag (the flag its parallel loops set on their own kernels), else ``{}``."""
    try:
        from numba.core.compiler import Flags
        from numba.core.cpu import CPUTargetOptions
        from numba.core.options import TargetOptions
    except ImportError:  # pragma: no cover - another Numba layout
        return {}
    if not hasattr(Flags, "noalias"):  # pragma: no cover
        return {}
    if not hasattr(CPUTargetOptions, "_noalias"):
        CPUTargetOptions._noalias = TargetOptions.Mapping("noalias")
    return {"_noalias": True}


NOALIAS = _noalias_option()
DISTINCT = {**BORROW, **NOALIAS}

_MASKED_NAMES: set[str] = set()
_EPILOGUE = "--prefer-predicate-over-epilogue="


def tail_masked(function):
    """Mark a block kernel (apply under ``@njit``) whose loop runs on a few pairs at a time
    (often fewer than a vector): LLVM vectorises its loops with masked (predicated) lanes
    and no scalar remainder, so a block of 2 to 7 pairs takes one vector iteration instead
    of 2 to 7 scalar ones. Only the marked kernels: long loops run slower masked (the
    streamed iterative kernel 10–16 %, the cull on 256 pairs 14 %). The option applies
    while LLVM optimises the kernel's own code (:func:`_install_tail_masking`); a Numba
    that does not offer that hook compiles the kernel as before (same results: the lanes
    compute what the scalar loop computes)."""
    _MASKED_NAMES.add(function.__qualname__)
    return function


def _install_tail_masking() -> None:
    """Wrap Numba's per-function LLVM optimisation (``CPUCodeLibrary.add_llvm_module``
    and ``finalize``, under Numba's global compiler lock) so that a library named after a
    :func:`tail_masked` kernel is optimised with LLVM's ``prefer-predicate-over-epilogue``
    option, and every other one without it."""
    try:
        from numba.core.codegen import CPUCodeLibrary
    except ImportError:  # pragma: no cover - another Numba layout
        return
    if getattr(CPUCodeLibrary, "_mrdem_masked", False):
        return

    def wrapped(method):
        def run(self, *args):
            if self.name not in _MASKED_NAMES:
                return method(self, *args)
            llvm.set_option("mrdem", _EPILOGUE + "predicate-else-scalar-epilogue")
            try:
                return method(self, *args)
            finally:
                llvm.set_option("mrdem", _EPILOGUE + "scalar-epilogue")

        return run

    for name in ("add_llvm_module", "finalize"):
        if hasattr(CPUCodeLibrary, name):
            setattr(CPUCodeLibrary, name, wrapped(getattr(CPUCodeLibrary, name)))
    CPUCodeLibrary._mrdem_masked = True


_install_tail_masking()


@intrinsic
def select(typingctx, cond, a, b):
    """``a if cond else b`` as one LLVM ``select``, for scalars and tuples alike.

    A conditional expression creates Numba-IR basic blocks; each block of an
    inlined helper is deep-copied along with the whole variable scope, which
    makes inlining quadratic. ``select`` keeps helpers one block long.
    """
    if a != b or not isinstance(cond, types.Boolean):
        return None
    sig = a(cond, a, b)

    def codegen(context, builder, signature, args):
        return _select(builder, args[0], args[1], args[2])

    return sig, codegen


def _select(builder, cond, x, y):
    """Element-wise ``select`` through nested aggregates (the vectoriser needs scalars)."""
    if isinstance(x.type, ir.LiteralStructType | ir.ArrayType):
        out = ir.Constant(x.type, ir.Undefined)
        n = len(x.type.elements) if isinstance(x.type, ir.LiteralStructType) else x.type.count
        for k in range(n):
            xk = builder.extract_value(x, k)
            yk = builder.extract_value(y, k)
            out = builder.insert_value(out, _select(builder, cond, xk, yk), k)
        return out
    return builder.select(cond, x, y)


@intrinsic
def sqrt(typingctx, x):
    """``llvm.sqrt`` of a float: vectorises, unlike the ``sqrtf`` libm call that
    ``math.sqrt`` and ``np.sqrt`` can lower to (errno semantics)."""
    if not isinstance(x, types.Float):
        return None
    sig = x(x)

    def codegen(context, builder, signature, args):
        fn = builder.module.declare_intrinsic("llvm.sqrt", [args[0].type])
        return builder.call(fn, [args[0]])

    return sig, codegen


@intrinsic(prefer_literal=True)
def stack_buffer(typingctx, count, dtype):
    """Room for ``count`` (a compile-time constant: a literal or a global name; an
    expression is typed as a run-time integer, and refused) elements of ``dtype`` in the calling
    kernel's stack frame, uninitialised, as a pointer for ``numba.carray``: an array with
    no allocation, no release and no atomic reference counts (it has no meminfo; Numba's
    reference counting skips a null one). Measured: four buffers of a small kernel, 357 →
    233 ns a call. The memory lives until the kernel returns: such an array must not be
    returned or kept (a buffer that must grow is replaced by an ``np.empty`` one)."""
    if not isinstance(count, types.IntegerLiteral) or count.literal_value < 1:
        return None
    if isinstance(dtype, types.DType):
        element = dtype.dtype
    elif isinstance(dtype, types.NumberClass):
        element = dtype.instance_type
    else:
        return None
    size = count.literal_value
    sig = types.CPointer(element)(count, dtype)

    def codegen(context, builder, signature, args):
        # in the function's entry block: one slot however often the call runs
        return cgutils.alloca_once(builder, context.get_data_type(element), size=size)

    return sig, codegen
