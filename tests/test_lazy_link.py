"""ftcreport's kernels load from the cache without parsing their linking IR until a compile links it
(jit/lazy_link.py, jit/compiling.py ``KernelLibrary.load``); another package's functions load as numba does.

Each check runs in a fresh process with its own cache directories (tmp_path), so the first process
compiles and saves and the second loads from the cache: the path the lazy load changes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

MODULE = textwrap.dedent(
    """
    import numpy as np
    from numba import njit
    from ftcreport.jit.compiling import jit

    @jit
    def poly(x):
        out = np.empty_like(x)
        for i in range(x.size):
            out[i] = 1.0 + x[i] * (2.0 + 3.0 * x[i])
        return out

    @njit(cache=True)
    def theirs(x):  # another package's function: numba's own cache load
        return x * 2.0
    """
)

# loads poly from the cache; reports what the load kept, then compiles a caller that links poly's IR
PROBE = textwrap.dedent(
    """
    import json
    import numpy as np
    import llvmlite.binding as ll
    from numba import njit
    from numba.core.codegen import JITCodeLibrary
    from ftcreport.jit import lazy_link
    from ftcreport.jit.compiling import KernelLibrary, jit
    import lazymod

    seen = {}  # the object code each load received (numba drops its copy once the engine has it)
    load = KernelLibrary.load.__func__

    def spy(cls, cg, state, below):
        seen[state[0]] = state[2][0]
        return load(cls, cg, state, below)

    KernelLibrary.load = classmethod(spy)  # this probe's own class: numba is not touched
    x = np.linspace(-1.0, 1.0, 7)
    y = lazymod.poly(x)
    lib = lazymod.poly.overloads[lazymod.poly.signatures[0]].library
    lazy = lib._shared_module is None and isinstance(lib._ftc_bitcode, bytes)
    bitcode = lib._ftc_bitcode
    elf = lazy_link.defined_symbols(seen[lib.name])
    mod = ll.parse_bitcode(bitcode)  # what numba itself would have read the names from
    eager = {g.name for gs in (mod.functions, mod.global_variables) for g in gs if not g.is_declaration}
    external = {f.name for f in mod.functions if not f.is_declaration and f.linkage == ll.Linkage.external}
    engine = lib.codegen._engine

    @jit(cache=False)
    def caller(x):
        return lazymod.poly(x).sum()

    s = caller(x)
    lazymod.theirs(x)
    theirs = lazymod.theirs.overloads[lazymod.theirs.signatures[0]].library
    print(json.dumps({
        "enabled": lazy_link.enabled(),
        "hits": lazymod.poly.stats.cache_hits.get(lazymod.poly.signatures[0], 0),
        "lazy": lazy,
        "y": y.tolist(),
        "sum": float(s),
        "elf_within_eager": sorted(elf - eager),
        "external_missing": sorted(external - elf),
        "registered": sorted(elf - engine._defined_symbols),
        "parsed_after_link": lib._shared_module is not None and lib._ftc_bitcode is None,
        "n_elf": len(elf),
        "theirs_hits": lazymod.theirs.stats.cache_hits.get(lazymod.theirs.signatures[0], 0),
        "theirs_numba": type(theirs) is JITCodeLibrary and theirs._shared_module is not None,
    }))
    """
)


def _python(code: str, folder: Path, **env: str) -> str:
    environ = dict(
        os.environ,
        FTCREPORT_CACHE=str(folder / "cache"),
        NUMBA_CACHE_DIR=str(folder / "numba"),
        PYTHONPATH=f"{folder}{os.pathsep}{ROOT}",
    )
    environ.update(env)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ, cwd=folder)
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_a_cached_kernel_loads_without_its_ir_and_links_later(tmp_path):
    (tmp_path / "lazymod.py").write_text(MODULE)
    # compile and save; the freshly compiled function's values
    first = _python(
        "import json, numpy as np, lazymod\nx = np.linspace(-1, 1, 7)\nlazymod.theirs(x)\n"
        "print(json.dumps(lazymod.poly(x).tolist()))",
        tmp_path,
    )
    expected = json.loads(first.splitlines()[-1])
    out = json.loads(_python(PROBE, tmp_path).splitlines()[-1])
    assert out["enabled"] and out["hits"] == 1  # loaded from the cache, through ftcreport's library class
    assert out["lazy"]  # the bitcode kept as bytes, not parsed
    # the same machine code as the compiling process ran: bit-identical values
    assert out["y"] == expected
    assert abs(out["sum"] - sum(expected)) <= 1e-12 * len(expected)  # a compiled reduction: round-off
    # the ELF names are a subset of numba's own set and hold every external function it would register
    assert out["elf_within_eager"] == [] and out["external_missing"] == [] and out["n_elf"] > 0
    assert out["registered"] == []  # and the engine knows them
    assert out["parsed_after_link"]  # linking the caller parsed the IR on demand
    assert out["theirs_hits"] == 1 and out["theirs_numba"]  # another package's function: numba's own load


def test_the_switch_parses_on_load(tmp_path):
    (tmp_path / "lazymod.py").write_text(MODULE)
    _python("import numpy as np, lazymod; lazymod.poly(np.zeros(3))", tmp_path)
    code = (
        "import numpy as np, lazymod\nfrom ftcreport.jit import lazy_link\n"
        "lazymod.poly(np.zeros(3))\nlib = lazymod.poly.overloads[lazymod.poly.signatures[0]].library\n"
        "print(lazy_link.enabled(), lib._shared_module is not None, lib._ftc_bitcode is None,"
        " lazymod.poly.stats.cache_hits.get(lazymod.poly.signatures[0], 0))"
    )
    assert _python(code, tmp_path, FTCREPORT_LAZY_LINK="0").split() == ["False", "True", "True", "1"]


def test_defined_symbols_rejects_what_is_not_elf64_little_endian():
    from ftcreport.jit.lazy_link import defined_symbols

    assert defined_symbols(b"\xcf\xfa\xed\xfe" + bytes(60)) is None  # a Mach-O header
    assert defined_symbols(b"\x7fELF\x01\x01" + bytes(60)) is None  # ELF32
    assert defined_symbols(b"") is None
