"""A binary BVH on the host (``BVHArrays``) and its SAH cost: what the builder
(``bvh_build``), the optimiser (``optimize``) and the device uploads share."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .layout import COUNT_SHIFT, LEAF_BIT

C_TRAV, C_TRI = 1.0, 1.0     # SAH costs of one node visit and one triangle test


@dataclass
class BVHArrays:
    """A BVH on the host.

    boxes: float32 (N, 12) per inner node: child A lo xyz, hi xyz, child B lo xyz, hi xyz
        (grown by ``pad_boxes``, so the triangle test never hits outside its box).
    children: uint32 (N, 2) child references (inner index or packed leaf).
    order: int64 (F,) original face index of each reordered triangle.
    levels: number of inner-node levels (<= MAX_LEVELS; the level-wise build counts the
        levels it made room for, ``optimize.reinsert`` the tree's height); leaf_count;
        sah_cost (relative to
        the root's surface area, C_trav = C_tri = 1); build_seconds;
    bounds: float64 (3,) lo, hi of all triangles.
    cells: None, or with spatial splits ``(lo, hi)`` float64 (F', 3) per leaf position: the
        cell its reference was cut to (``renderer.accel.spatial``); ``order`` then holds a
        face once per reference.
    optimize_seconds: the part of build_seconds spent in ``renderer.accel.optimize``.
    raw: None, or float32 (N, 12) the child boxes before padding, exactly the bounds of
        each child's float32 triangles (``bvh_build.raw_boxes``), kept with a cached tree
        so the traversal pads them for its ray origins without a refit.
    """

    boxes: np.ndarray
    children: np.ndarray
    order: np.ndarray
    levels: int
    leaf_count: int
    sah_cost: float
    build_seconds: float
    bounds: tuple = (np.zeros(3), np.zeros(3))
    cells: tuple | None = None
    optimize_seconds: float = 0.0
    raw: np.ndarray | None = None

    @property
    def node_count(self) -> int:
        return int(self.boxes.shape[0])


def half_area(lo, hi):
    """Half the surface area of the box(es) ``(lo, hi)`` (xyz along the first axis)."""
    d = hi - lo
    return d[0] * d[1] + d[1] * d[2] + d[2] * d[0]


def sah_cost(a: BVHArrays) -> float:
    """SAH cost relative to the root box: C_trav per inner node + C_tri per leaf triangle,
    each weighted by its box's surface area."""
    lo, hi = a.bounds
    root = float(half_area(np.asarray(lo, np.float64), np.asarray(hi, np.float64)))
    if root <= 0 or a.node_count == 0:
        return 0.0
    bx = a.boxes.astype(np.float64)
    total = C_TRAV * root
    for k in range(2):
        box = bx[:, 6 * k:6 * k + 6]
        with np.errstate(invalid="ignore"):
            area = half_area(box[:, 0:3].T, box[:, 3:6].T)
        area = np.where(np.isfinite(area), area, 0.0)
        ref = a.children[:, k].astype(np.int64)
        is_leaf = (ref & LEAF_BIT) != 0
        count = ((ref >> COUNT_SHIFT) & 15) + 1
        total += float(np.sum(np.where(is_leaf, C_TRI * count * area, C_TRAV * area)))
    return total / root
