"""Names for Numba's machine code in Linux ``perf`` profiles: a ``/tmp/perf-<pid>.map``.

``perf record`` samples compiled kernels at their true cost (no tracer, no stopped
process), but Numba's code lives in anonymous memory that perf cannot name. This module
records every object file Numba loads or compiles after :func:`install` and
:func:`write` lists its functions (the kernels and the helpers LLVM kept apart) with their
load addresses in the map file that ``perf report`` reads.

Use it in the profiled script::

    import perf_map; perf_map.install()    # before the first kernel is loaded
    ...                                    # load or compile the kernels, warm up
    perf_map.write()                       # after the last kernel is loaded

and run ``perf record -F 2999 -o p.data python script.py``, then ``perf report -i p.data
--no-children --sort symbol``. To sample one phase only, start perf disabled (``-D -1
--control fifo:CTL``) and write ``enable`` / ``disable`` to the fifo around it. Needs
``nm`` (binutils). It reaches into Numba's code library (``CPUCodeLibrary``'s object
hooks, Numba 0.68), which is why it is a benchmark tool and not part of the engine.
BENCHMARKS.md (issue 15, ninth step) shows what it found.
"""

from __future__ import annotations

import os
import subprocess
import tempfile

OBJECTS: list[bytes] = []
"""Object files Numba loaded (from its cache) or compiled since :func:`install`."""


def install() -> None:
    """Record the object code of every library Numba finalises from now on."""
    from numba.core import codegen

    library = codegen.CPUCodeLibrary
    loaded, compiled = library._object_getbuffer_hook, library._object_compiled_hook

    def getbuffer(cls, ll_module):
        buffer = loaded.__func__(cls, ll_module)
        if buffer:
            OBJECTS.append(bytes(buffer))
        return buffer

    def on_compiled(cls, ll_module, buffer):
        OBJECTS.append(bytes(buffer))
        return compiled.__func__(cls, ll_module, buffer)

    library._object_getbuffer_hook = classmethod(getbuffer)
    library._object_compiled_hook = classmethod(on_compiled)


def _symbols(obj: bytes) -> list[tuple[int, int, str, bool]]:
    """``(value, size, name, global)`` of the code symbols of one object file."""
    with tempfile.NamedTemporaryFile(suffix=".o") as file:
        file.write(obj)
        file.flush()
        listing = subprocess.run(
            ["nm", "-S", "--defined-only", file.name], capture_output=True, text=True, check=True
        ).stdout
    out = []
    for line in listing.splitlines():
        fields = line.split()
        if len(fields) == 4 and fields[2] in ("t", "T", "W"):
            out.append((int(fields[0], 16), int(fields[1], 16), fields[3], fields[2] == "T"))
    return out


def write(path: str | None = None) -> int:
    """Write the map (default ``/tmp/perf-<pid>.map``); returns the number of functions.

    Each object's code section is placed from the address the JIT engine gives one of its
    global functions; the other functions (local or weak) keep their offsets from it."""
    from numba.core.registry import cpu_target

    engine = cpu_target.target_context.codegen()._engine
    named: dict[int, tuple[int, str]] = {}
    for obj in OBJECTS:
        symbols = _symbols(obj)
        base = None
        for value, _, name, is_global in symbols:
            if is_global:
                address = engine.get_function_address(name)
                if address:
                    base = address - value
                    break
        if base is None:
            continue
        for value, size, name, _ in symbols:
            named[base + value] = (size, name)
    with open(path or f"/tmp/perf-{os.getpid()}.map", "w") as out:
        for address, (size, name) in sorted(named.items()):
            out.write(f"{address:x} {size:x} {name}\n")
    return len(named)
