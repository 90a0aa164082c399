"""numba's cached libraries without their linking IR until something links them (memory, issue 20 item 7).

numba caches a compiled function as its machine code (an ELF object) plus the LLVM bitcode of the
whole library, "for further inlining with other libraries" (``CPUCodeLibrary.serialize_using_object_code``).
On loading from the cache it parses that bitcode into an LLVM module at once
(``CPUCodeLibrary._unserialize``), although only a later compile that calls the function links it,
and keeps the module for the life of the process; it reads the module only for the names of the
symbols it defines (``JitEngine._load_defined_symbols``).  The closed loop's library inlines every
kernel it calls: 2.2 MB of bitcode, about 32 MB once parsed (measured: VmRSS around
``llvmlite.binding.parse_bitcode``), for a run that never compiles.

:func:`install` makes the load keep the bitcode as bytes, take the symbol names from the object's
ELF symbol table (its defined global and weak symbols: the names the execution engine can resolve),
and parse the bitcode on the first ``_get_module_for_linking`` (a compile that calls the function).
The machine code run is numba's own, loaded the same way: the numbers cannot change.

It replaces two methods of numba's ``CPUCodeLibrary`` (read in numba 0.68), so it checks that the
internals it uses exist and otherwise leaves numba alone; ``FTCREPORT_LAZY_LINK=0`` turns it off.  Objects that are
not ELF64 little-endian (macOS, Windows) take numba's own path.
"""

from __future__ import annotations

import os
import struct

__all__ = ["defined_symbols", "install", "installed"]

_STATE = {"installed": False}


def defined_symbols(obj: bytes) -> set[str] | None:
    """Names of the global and weak symbols an ELF64 little-endian object defines; None if not one.

    ELF layout (System V ABI, ELF-64 Object File Format 1.5): header fields e_shoff at 0x28,
    e_shentsize and e_shnum at 0x3A; section headers (sh_name, sh_type, sh_flags, sh_addr,
    sh_offset, sh_size, sh_link, ...); a SHT_SYMTAB (type 2) section of 24-byte Elf64_Sym
    (st_name, st_info, st_other, st_shndx, st_value, st_size) whose sh_link is its string table.
    """
    if len(obj) < 64 or obj[:4] != b"\x7fELF" or obj[4] != 2 or obj[5] != 1:
        return None
    (shoff,) = struct.unpack_from("<Q", obj, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", obj, 0x3A)
    sections = [struct.unpack_from("<IIQQQQII", obj, shoff + i * shentsize) for i in range(shnum)]
    out: set[str] = set()
    for _name, kind, _flags, _addr, offset, size, link, _info in sections:
        if kind != 2:  # SHT_SYMTAB
            continue
        strings = sections[link][4]
        for at in range(offset, offset + size, 24):
            st_name, st_info, _other, st_shndx = struct.unpack_from("<IBBH", obj, at)
            # defined (st_shndx != SHN_UNDEF) and not local (binding st_info >> 4: 1 global, 2 weak)
            if st_shndx == 0 or st_info >> 4 not in (1, 2):
                continue
            start = strings + st_name
            out.add(obj[start : obj.index(b"\0", start)].decode())
    return out


def installed() -> bool:
    """Whether the lazy load is in place in this process."""
    return _STATE["installed"]


def install() -> bool:
    """Patch numba's cache load (once per process); returns whether it is in place."""
    if _STATE["installed"] or os.environ.get("FTCREPORT_LAZY_LINK", "1") == "0":
        return _STATE["installed"]
    try:
        from numba.core import codegen
    except ImportError:  # pragma: no cover - numba is a dependency
        return False
    lib = getattr(codegen, "CPUCodeLibrary", None)
    engine = getattr(codegen, "JitEngine", None)
    needed = ("_unserialize", "_get_module_for_linking", "enable_object_caching", "_set_compiled_object")
    needed += ("_finalize_final_module",)
    if lib is None or engine is None or not all(hasattr(lib, a) for a in needed):
        return False
    ll = getattr(codegen, "ll", None)  # numba's own llvmlite.binding
    if not hasattr(engine, "_load_defined_symbols") or not hasattr(ll, "parse_bitcode"):
        return False
    numba_unserialize = lib.__dict__["_unserialize"].__func__
    numba_linking = lib._get_module_for_linking

    def _unserialize(cls, cg, state):
        name, kind, data = state
        symbols = defined_symbols(data[0]) if kind == "object" else None
        if symbols is None:
            return numba_unserialize(cls, cg, state)
        object_code, shared_bitcode = data
        self = cg.create_library(name)
        self.enable_object_caching()
        self._set_compiled_object(object_code)
        self._ftc_bitcode = shared_bitcode  # parsed by _get_module_for_linking, if ever
        self._finalize_final_module()
        cg._engine._defined_symbols |= symbols
        return self

    def _get_module_for_linking(self):
        bitcode = getattr(self, "_ftc_bitcode", None)
        if bitcode is not None:
            self._shared_module = ll.parse_bitcode(bitcode)
            self._ftc_bitcode = None
        return numba_linking(self)

    lib._unserialize = classmethod(_unserialize)
    lib._get_module_for_linking = _get_module_for_linking
    _STATE["installed"] = True
    return True
