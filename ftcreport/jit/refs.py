r"""The kernels' parameter tuples behind one pointer, so that calls between kernels stay cheap to compile.

numba passes a NamedTuple by value: every array field is seven machine words, and a call
between two kernels copies (and reference-counts) every field of every tuple it passes.  The
loop's tuples (the scheme's parameters, the kinematic law, the reference, the chain, the
per-step cache) flatten to about 700 words, and compiling each call site of them was most of a
cold start: 160 s for the whole loop on the 2-core machine.  :func:`as_ref` copies a NamedTuple
into a numba StructRef with the same field names, once, at the loop's entry; the kernels then
read ``P.gamma`` from it exactly as from the tuple, and every call passes one pointer.  Nested
NamedTuples become nested refs.  Nothing numerical changes: the fields are the same arrays.

Python passes refs too (:func:`to_ref`, a :class:`RefProxy`): a kernel that both Python and the loop
call (the references' checks ``ref_jets``/``ref_point``, the metrics' ``wheel_speeds_rows`` and
``switching_costs_rows``, ``reduced``) is then compiled once, for the ref, and the loop's compile
and Python's share it; with the NamedTuple from Python every such kernel and the kernels below it
were compiled twice (docs/ENGINE.md, "Compile time (session 9)").
"""

from __future__ import annotations

from numba import types
from numba.core.extending import overload
from numba.experimental import structref

from .compiling import KernelCompiler, jit

__all__ = ["RefProxy", "RefType", "as_ref", "to_ref"]


@structref.register
class RefType(types.StructRef):
    """A StructRef with a NamedTuple's fields (nested NamedTuples as RefType too)."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


def _ref_type(t):
    """The type a field of type ``t`` has in the ref: nested NamedTuples become refs."""
    if isinstance(t, types.BaseNamedTuple):
        return RefType(tuple((name, _ref_type(ft)) for name, ft in zip(t.fields, t.types, strict=True)))
    return t


def as_ref(x):
    """``x`` (a NamedTuple) behind one pointer, a plain tuple item by item; anything else unchanged.

    Compiled code only (an overload): ``as_ref(P)`` at a loop's entry.
    """
    raise NotImplementedError("as_ref runs in compiled code only")


@overload(as_ref, jit_options={"pipeline_class": KernelCompiler})  # ftcreport's compiler: cheap below an entry
def _as_ref(x):
    if isinstance(x, types.BaseTuple) and not isinstance(x, types.BaseNamedTuple):  # a plain tuple: each item
        items = ", ".join(f"as_ref(x[{i}])" for i in range(len(x.types)))
        scope = {"as_ref": as_ref}
        exec(f"def impl(x):\n    return ({items},)", scope)
        return scope["impl"]
    if isinstance(x, RefType) or not isinstance(x, types.BaseNamedTuple):
        return lambda x: x
    T = _ref_type(x)
    lines = ["def impl(x):", "    r = new(T)"]
    for name, ft in zip(x.fields, x.types, strict=True):
        if isinstance(ft, types.BaseNamedTuple):
            lines.append(f"    r.{name} = as_ref(x.{name})")
        else:
            lines.append(f"    r.{name} = x.{name}")
    lines.append("    return r")
    scope = {"new": structref.new, "T": T, "as_ref": as_ref}
    exec("\n".join(lines), scope)  # the fields unrolled: numba cannot loop over heterogeneous fields
    return scope["impl"]


class RefProxy(structref.StructRefProxy):
    """A ref held by Python (:func:`to_ref`): a kernel called with it is typed as the loop types the ref.

    It keeps the tuple's arrays alive (the ref holds them); Python reads the fields from the tuple."""

    __slots__ = ()

    def __repr__(self) -> str:
        return f"<RefProxy {self._type}>"


structref.define_boxing(RefType, RefProxy)


@jit(error_model="python")
def _to_ref(x):
    return as_ref(x)


def to_ref(x) -> RefProxy:
    """``x`` (a NamedTuple of the kernels: ``Ref``, ``Chain``, ``Law``, ...) as the loop's ``as_ref(x)``.

    A kernel that Python calls with it is compiled for the same argument types as the loop's call of it,
    so one compile serves both.  The ref shares the tuple's arrays (no copy).
    """
    return _to_ref(x)
