"""ftcreport.fast.lazy_link: numba's cache loads keep the linking IR unparsed until a compile links it.

Each check runs in a fresh process with its own numba cache directory (tmp_path), so the first
process compiles and saves and the second loads from the cache: the path the patch changes.
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

    @njit(cache=True)
    def poly(x):
        out = np.empty_like(x)
        for i in range(x.size):
            out[i] = 1.0 + x[i] * (2.0 + 3.0 * x[i])
        return out
    """
)

# loads poly from the cache; reports what the load kept, then compiles a caller that links poly's IR
PROBE = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import ftcreport.fast  # installs the lazy load
    from ftcreport.fast import lazy_link
    from numba import njit
    from numba.core import codegen
    import llvmlite.binding as ll
    import lazymod

    seen = {}  # the object code each load received (numba drops its copy once the engine has it)
    patched = codegen.CPUCodeLibrary.__dict__["_unserialize"].__func__

    def spy(cls, cg, state):
        seen[state[0]] = state[2][0]
        return patched(cls, cg, state)

    codegen.CPUCodeLibrary._unserialize = classmethod(spy)
    x = np.linspace(-1.0, 1.0, 7)
    y = lazymod.poly(x)
    lib = lazymod.poly.overloads[lazymod.poly.signatures[0]].library
    lazy = lib._shared_module is None and isinstance(getattr(lib, "_ftc_bitcode", None), bytes)
    bitcode = lib._ftc_bitcode
    obj = seen[lib.name]
    elf = lazy_link.defined_symbols(obj)
    mod = ll.parse_bitcode(bitcode)  # what numba itself would have read the names from
    eager = {g.name for gs in (mod.functions, mod.global_variables) for g in gs if not g.is_declaration}
    external = {f.name for f in mod.functions if not f.is_declaration and f.linkage == ll.Linkage.external}
    engine = lib.codegen._engine

    @njit
    def caller(x):
        return lazymod.poly(x).sum()

    s = caller(x)
    print(json.dumps({
        "installed": lazy_link.installed(),
        "hits": lazymod.poly.stats.cache_hits.get(lazymod.poly.signatures[0], 0),
        "lazy": lazy,
        "y": y.tolist(),
        "sum": float(s),
        "elf_within_eager": sorted(elf - eager),
        "external_missing": sorted(external - elf),
        "registered": sorted(elf - engine._defined_symbols),
        "parsed_after_link": lib._shared_module is not None,
        "n_elf": len(elf),
    }))
    """
)


def _python(code: str, folder: Path, **env: str) -> str:
    environ = dict(os.environ, NUMBA_CACHE_DIR=str(folder / "cache"), PYTHONPATH=f"{folder}{os.pathsep}{ROOT}")
    environ.update(env)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ, cwd=folder)
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_a_cached_function_loads_without_its_ir_and_links_later(tmp_path):
    (tmp_path / "lazymod.py").write_text(MODULE)
    # compile and save; the freshly compiled function's values
    first = _python(
        "import json, numpy as np, lazymod; print(json.dumps(lazymod.poly(np.linspace(-1, 1, 7)).tolist()))", tmp_path
    )
    expected = json.loads(first.splitlines()[-1])
    out = json.loads(_python(PROBE, tmp_path).splitlines()[-1])
    assert out["installed"] and out["hits"] == 1  # loaded from the cache, through the patch
    assert out["lazy"]  # the bitcode kept as bytes, not parsed
    # the same machine code as the compiling process ran: bit-identical values
    assert out["y"] == expected
    assert abs(out["sum"] - sum(expected)) <= 1e-12 * len(expected)  # a compiled reduction: round-off
    # the ELF names are a subset of numba's own set and hold every external function it would register
    assert out["elf_within_eager"] == [] and out["external_missing"] == [] and out["n_elf"] > 0
    assert out["registered"] == []  # and the engine knows them
    assert out["parsed_after_link"]  # linking the caller parsed the IR on demand


def test_the_switch_leaves_numba_alone(tmp_path):
    (tmp_path / "lazymod.py").write_text(MODULE)
    _python("import numpy as np, lazymod; lazymod.poly(np.zeros(3))", tmp_path)
    code = (
        "import numpy as np, ftcreport.fast, lazymod\nfrom ftcreport.fast import lazy_link\n"
        "lazymod.poly(np.zeros(3))\nlib = lazymod.poly.overloads[lazymod.poly.signatures[0]].library\n"
        "print(lazy_link.installed(), lib._shared_module is not None)"
    )
    assert _python(code, tmp_path, FTCREPORT_LAZY_LINK="0").split() == ["False", "True"]


def test_defined_symbols_rejects_what_is_not_elf64_little_endian():
    from ftcreport.fast.lazy_link import defined_symbols

    assert defined_symbols(b"\xcf\xfa\xed\xfe" + bytes(60)) is None  # a Mach-O header
    assert defined_symbols(b"\x7fELF\x01\x01" + bytes(58)) is None  # ELF32
    assert defined_symbols(b"") is None
