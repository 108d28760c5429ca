"""Where the watertight routine's time goes: variants of ``renderer.accel.triangle.watertight``
that each drop one part (wrong on purpose: for timing only, never for rendering), measured
through the same BVH on the routine-cost batches (``lab.probes.routine_cost.measure``).

    PYTHONPATH=. python lab/probes/routine_variants.py BACKEND WIDTH HEIGHT SCENES \
        [REPEATS [OUT.json]]

e.g. ``cuda 1920 1080 cornell_box,bunny,conference 7 out.json`` (``lab/notes/
watertight-variants.md``). The variants are registered in ``ROUTINES`` only in this process.
"""
import json
import sys

import drjit as dr

from evaluation import routine_cost as RC
from renderer.accel import triangle as T
from renderer.scene import load_scene


def variant(delta=True, f64=True, perm=True, tplane=True):
    def wt(o, d, p0, p1, p2, n, t_min=0.0):
        double = dr.type_v(o) == dr.VarType.Float64
        a0, a1, a2 = p0 - o, p1 - o, p2 - o
        if perm:
            ad = dr.abs(d)
            zx = (ad.x > ad.y) & (ad.x > ad.z)
            zy = ~(ad.x > ad.y) & (ad.y > ad.z)
            dx, dy, dz = T._rotate(d, zx, zy)
            x0, y0, z0 = T._rotate(a0, zx, zy)
            x1, y1, z1 = T._rotate(a1, zx, zy)
            x2, y2, z2 = T._rotate(a2, zx, zy)
        else:
            dx, dy, dz = d.x, d.y, d.z
            x0, y0, z0 = a0.x, a0.y, a0.z
            x1, y1, z1 = a1.x, a1.y, a1.z
            x2, y2, z2 = a2.x, a2.y, a2.z
        inv_dz = 1.0 / dz
        sx, sy = -dx * inv_dz, -dy * inv_dz
        x0, y0 = dr.fma(sx, z0, x0), dr.fma(sy, z0, y0)
        x1, y1 = dr.fma(sx, z1, x1), dr.fma(sy, z1, y1)
        x2, y2 = dr.fma(sx, z2, x2), dr.fma(sy, z2, y2)
        e0 = T.difference_of_products(x1, y2, y1, x2)
        e1 = T.difference_of_products(x2, y0, y2, x0)
        e2 = T.difference_of_products(x0, y1, y0, x1)
        if f64 and not double:
            e0, e1, e2 = dr.if_stmt(((x0, y0, x1, y1, x2, y2), (e0, e1, e2)),
                                    (e0 == 0) | (e1 == 0) | (e2 == 0),
                                    T._edges_float64, T._edges_as_they_are)
        mixed = ((e0 < 0) | (e1 < 0) | (e2 < 0)) & ((e0 > 0) | (e1 > 0) | (e2 > 0))
        det = e0 + e1 + e2
        z0, z1, z2 = z0 * inv_dz, z1 * inv_dz, z2 * inv_dz
        inv_det = 1.0 / det
        if tplane:
            t = dr.dot(a0, n) / dr.dot(d, n)
        else:
            t = (e0 * z0 + e1 * z1 + e2 * z2) * inv_det
        u, v = e1 * inv_det, e2 * inv_det
        hit = ~mixed & (det != 0) & dr.isfinite(t) & (t > t_min)
        if delta:
            max_z = dr.maximum(dr.maximum(dr.abs(z0), dr.abs(z1)), dr.abs(z2))
            max_x = dr.maximum(dr.maximum(dr.abs(x0), dr.abs(x1)), dr.abs(x2))
            max_y = dr.maximum(dr.maximum(dr.abs(y0), dr.abs(y1)), dr.abs(y2))
            g2, g3, g5 = (T._gamma(k, double) for k in (2, 3, 5))
            delta_z = g3 * max_z
            delta_x = g5 * (max_x + max_z)
            delta_y = g5 * (max_y + max_z)
            delta_e = 2.0 * (g2 * max_x * max_y + delta_y * max_x + delta_x * max_y)
            max_e = dr.maximum(dr.maximum(dr.abs(e0), dr.abs(e1)), dr.abs(e2))
            delta_t = (3.0 * (g3 * max_e * max_z + delta_e * max_z + delta_z * max_e)
                       * dr.abs(inv_det))
            hit &= t > delta_t
        return t, u, v, hit
    wt.layout = "vertices"
    return wt


T.ROUTINES["wt_nodelta"] = variant(delta=False)
T.ROUTINES["wt_nof64"] = variant(f64=False)
T.ROUTINES["wt_noperm"] = variant(perm=False)
T.ROUTINES["wt_tedge"] = variant(tplane=False)
T.ROUTINES["wt_bare"] = variant(delta=False, f64=False, perm=False)
T.ROUTINES["wt_copy"] = variant()


def main(argv) -> int:
    import renderer.accel as A
    A.ROUTINES.update(T.ROUTINES)
    RC.ROUTINES.update(T.ROUTINES)
    backend, w, h = argv[0], int(argv[1]), int(argv[2])
    repeats = int(argv[4]) if len(argv) > 4 else 5
    out = []
    for s in argv[3].split(","):
        rows = RC.measure(load_scene(f"scenes/{s}.toml"), backend, w, h, repeats=repeats)
        for r in rows:
            base = r["watertight"]
            print(s, r["batch"], " ".join(f"{k}={r[k]:.0f}({r[k] / base:.2f})"
                                          for k in T.ROUTINES), flush=True)
        out += rows
    if len(argv) > 5:
        with open(argv[5], "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
