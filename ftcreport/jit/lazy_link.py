"""numba's cached libraries without their linking IR until something links them (memory, issue 20 item 7).

numba caches a compiled function as its machine code (an ELF object) plus the LLVM bitcode of the
whole library, "for further inlining with other libraries" (``CPUCodeLibrary.serialize_using_object_code``).
Its own load parses that bitcode into an LLVM module at once, although only a later compile that calls
the function links it, and keeps the module for the life of the process; it reads the module only for
the names of the symbols it defines.  The closed loop's library inlines every kernel it calls: 2.2 MB of
bitcode, about 32 MB once parsed (measured: VmRSS around ``llvmlite.binding.parse_bitcode``), for a run
that never compiles.

ftcreport's kernels load from the cache into their own library class
(:meth:`ftcreport.jit.compiling.KernelLibrary.load`), which keeps the bitcode as bytes, takes the
symbol names from the object's ELF symbol table (:func:`defined_symbols`: its defined global and weak
symbols, the names the execution engine can resolve) and parses the bitcode on the first link.  The
machine code run is numba's own, loaded the same way: the numbers cannot change.  Only ftcreport's
kernels load so; another package's functions load through numba's own classes.
``FTCREPORT_LAZY_LINK=0`` parses on load, as numba does; objects that are not ELF64 little-endian
(macOS, Windows) are parsed on load too.
"""

from __future__ import annotations

import os
import struct

__all__ = ["defined_symbols", "enabled"]


def enabled() -> bool:
    """Whether ftcreport's cache loads may keep the linking IR unparsed (``FTCREPORT_LAZY_LINK=0``: not).

    The caller (``compiling``) also requires the acceleration to be on; this module imports nothing of
    ftcreport, so the two never import each other."""
    return os.environ.get("FTCREPORT_LAZY_LINK", "1") != "0"


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
