"""What a cold first result compiles (issue 20 item 1): Python's calls share the loop's compiles.

The time itself is measured in benchmarks/run.py (``--only-first-result``), never here; these are the
contracts that make the compiles shared and the numbers unchanged (tests/test_golden.py holds them).
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
from numba import typeof

from ftcreport.fast import kernels as F
from ftcreport.jit.refs import RefProxy, RefType, _ref_type, to_ref
from ftcreport.references import FlatReference, eight


def test_the_references_call_their_kernels_with_the_loops_ref_type():
    ref = FlatReference(eight(scale=2.0), [1.7, 1.2])
    point = ref.at(0.3)
    R = ref._kernel_ref()
    assert isinstance(R, RefProxy)
    # the type the loop's as_ref(R) gives: one compile of ref_jets/ref_point serves the loop and Python
    assert typeof(R) == _ref_type(typeof(ref.packed())) and isinstance(typeof(R), RefType)
    assert any(sig[0] == typeof(R) for sig in F.ref_jets.signatures)
    assert any(sig[0] == typeof(R) for sig in F.ref_point.signatures)
    # the jets at t = 0.3 from a fresh ref are the same evaluation: equal to the last bit
    info = np.zeros(4)
    jets = F.ref_jets(to_ref(ref.packed()), 0.3, info)
    assert info[0] == 0
    q_d, eta_d, eta_d_dot, sc = np.empty(5), np.empty(2), np.empty(2), np.empty(4)
    F.ref_point(to_ref(ref.packed()), jets, 0.3, 0.0, info, q_d, eta_d, eta_d_dot, sc, np.empty((7, 3)))
    assert np.array_equal(q_d, point.q_d) and np.array_equal(eta_d_dot, point.eta_d_dot)


def test_a_ref_holds_the_tuples_arrays():
    ref = FlatReference(eight(theta0_deg=None), [1.7])  # unrotated: x_d = 3 sin(0.3 t)
    R = ref.packed()
    proxy = to_ref(R)
    # the path jets read the same xterms array: doubling the tuple's amplitude doubles the ref's xdot(0)
    before = F.path_jets(proxy, 0.0)[0].copy()
    R.xterms[0, 0] *= 2.0
    after = F.path_jets(proxy, 0.0)[0]
    assert before[1] == 3.0 * 0.3  # xdot(0) = A w (sin(pi/2) = 1 exactly, no rotation)
    assert after[1] == 2.0 * before[1]  # exact: a product scaled by 2


def test_a_reference_pickles_without_its_ref():
    ref = FlatReference(eight(), [1.7])
    a = ref.at(1.25)
    for other in (pickle.loads(pickle.dumps(ref)), copy.deepcopy(ref)):
        assert other._ref is None  # a pointer into this process: rebuilt on the first use
        b = other.at(1.25)
        assert np.array_equal(a.q_d, b.q_d) and np.array_equal(a.eta_d_dot, b.eta_d_dot)
