"""The node layout every accelerator's tree and traversal share.

A node reference (a BVH's children, a traversal's current node and stack entries) is a
UInt32: an inner-node index, a packed leaf ``LEAF_BIT | (count - 1) << COUNT_SHIFT |
first`` (``count`` triangles from position ``first`` of the accelerator's triangle
order), or ``DONE``. A traversal's stack holds ``STACK_SIZE`` references. The builders
bound a binary tree's inner levels by ``MAX_LEVELS``, which the binary traversal's stack
holds; the wide collapse expands a node's children only while the pushes they need stay
within ``STACK_SIZE`` (``wide.collapse``), so no stack can overflow.
"""
from __future__ import annotations

import numpy as np

LEAF_BIT = 1 << 31
COUNT_SHIFT = 27
FIRST_MASK = (1 << COUNT_SHIFT) - 1
MAX_LEAF = 16                # leaf size limit of the packed reference (4 count bits)
DONE = 0xFFFFFFFF            # "no node left" sentinel of the traversal
#: UInt32 entries per ray (256 bytes, left uninitialised: Dr.Jit 1.5's LLVM backend
#: crashed on zero-filled local arrays over 128 bytes, drjit issue #532, and a stack needs
#: no fill): ``MAX_LEVELS`` and the room a wide collapse fills with children on a tree's
#: deepest paths.
STACK_SIZE = 64
#: Inner levels of a binary tree, the most its traversal pushes: above the depth PLOC's
#: clustering reaches on the bundled scenes (Conference's 36), so that no subtree of theirs
#: is rebuilt to fit, with 16 entries of ``STACK_SIZE`` left at least.
MAX_LEVELS = 48


def leaf_ref(first, count):
    """Packed leaf reference(s) of ``count`` triangles from ``first``: uint32."""
    first = np.asarray(first, np.uint64)
    count = np.asarray(count, np.uint64)
    return (np.uint64(LEAF_BIT) | ((count - np.uint64(1)) << np.uint64(COUNT_SHIFT))
            | first).astype(np.uint32)
