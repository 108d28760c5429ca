"""The node layout every accelerator's tree and traversal share.

A node reference (a BVH's children, a traversal's current node and stack entries) is a
UInt32: an inner-node index, a packed leaf ``LEAF_BIT | (count - 1) << COUNT_SHIFT |
first`` (``count`` triangles from position ``first`` of the accelerator's triangle
order), or ``DONE``. A traversal's stack holds ``STACK_SIZE`` references, and the builders
bound a tree's inner levels by the same number, so the stack cannot overflow.
"""
from __future__ import annotations

import numpy as np

LEAF_BIT = 1 << 31
COUNT_SHIFT = 27
FIRST_MASK = (1 << COUNT_SHIFT) - 1
MAX_LEAF = 16                # leaf size limit of the packed reference (4 count bits)
DONE = 0xFFFFFFFF            # "no node left" sentinel of the traversal
#: UInt32 entries per ray: 128 bytes, the largest local array Dr.Jit 1.5's LLVM backend
#: compiles (drjit issue #532).
STACK_SIZE = 32
MAX_LEVELS = STACK_SIZE      # inner levels of a tree; the stack never holds more entries


def leaf_ref(first, count):
    """Packed leaf reference(s) of ``count`` triangles from ``first``: uint32."""
    first = np.asarray(first, np.uint64)
    count = np.asarray(count, np.uint64)
    return (np.uint64(LEAF_BIT) | ((count - np.uint64(1)) << np.uint64(COUNT_SHIFT))
            | first).astype(np.uint32)
