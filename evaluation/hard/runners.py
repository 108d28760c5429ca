"""The hard cases, one function each, registered in ``CASES`` under the table's name; each
returns ``Row``s (case, variant, criterion, measured, pass). ``run_suite`` runs a selection
for every accelerator, triangle routine and precision of a ``Config``."""

from __future__ import annotations

import math
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import drjit as dr
import numpy as np

from renderer.accel import DEFAULT_ROUTINE, Ray, build_accelerator
from renderer.device import array3, types
from renderer.scene import Scene, Settings, shapes
from renderer.shade import SurfacePoint

from .cases import OVERRIDE_EPSILON, PARITY_TIES_BY_DESIGN, Config, Row, load_cases, variants
from .far import case_far_snapped
from .rays import (
    ball_points,
    closest_hit,
    device_interior_misses,
    mesh_edges,
    ray_answers,
    spawn_origin,
    time_rays,
    unit_vectors,
)
from .scenes import (
    camera,
    closed_mesh_scene,
    degenerate_scene,
    grid,
    material,
    mesh_scene,
    parity_scenes,
    point_light,
    robust_scenes,
    room_scene,
    sphere_object,
    terminator_scene,
)


# ---- case 1: closed mesh from inside ------------------------------------------------------
def case_closed_mesh(cfg: Config, spec: dict) -> list[Row]:
    """Rays from random interior points of a closed icosphere far from the origin in random
    directions, rays aimed exactly at its vertices and edge midpoints, tinybvh's
    axis-aligned directions with ±0 components, and rays aimed at a tessellated plane from
    above: every one must hit. Misses are counted per (accel, routine, precision); the
    criterion (``max_misses``) applies to the default routine, the others are reported."""
    c = np.asarray(spec["center"], np.float64)
    r = float(spec["radius"])
    V, F = shapes.make_shape("sphere", subdivisions=int(spec["subdivisions"]))
    V = V * r + c
    side = 4 * r
    PV, PF = grid(int(spec["plane_grid"]), side, c + [0, -3 * r, 0])
    scene = mesh_scene([(V, F, 0), (PV, PF, 0)], [material(kd=0.5)])
    n_rays = int(cfg.rays or spec["rays"])
    rows = []
    edges = mesh_edges(F)
    zero_dirs = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            for zs in ((0.0, 0.0), (0.0, -0.0), (-0.0, 0.0), (-0.0, -0.0)):
                v = [zs[0], zs[1]]
                v.insert(axis, sign)
                zero_dirs.append(v)
    zero_dirs = np.array(zero_dirs)
    for accel, routine, prec in variants(cfg):
        t = types(cfg.backend, prec)
        acc = build_accelerator(accel, scene, t, intersection=routine)
        n = n_rays if accel == "bvh" else max(n_rays // int(spec["brute_divisor"]), 1000)
        info = _closed_mesh_counts(acc, t, cfg, n, c, r, V, edges, zero_dirs, side)
        total_miss = sum(v["misses"] for v in info.values())
        total_rays = sum(v["rays"] for v in info.values())
        info["ns_per_ray"] = time_rays(acc, t, cfg, c, r, min(n, 1 << 22))
        default = routine == DEFAULT_ROUTINE
        limit = int(spec["max_misses"])
        rows.append(Row(
            case="1 closed mesh", variant=f"{accel}/{routine}/{prec}",
            criterion=(f"misses <= {limit}" if default else "misses reported (not default)"),
            measured=(f"{total_miss} misses in {total_rays} rays ("
                      + ", ".join(f"{g}: {v['misses']}/{v['rays']}" for g, v in info.items()
                                  if isinstance(v, dict))
                      + f"); {info['ns_per_ray']:.0f} ns/ray"),
            passed=(total_miss <= limit) if default else True, value=float(total_miss),
            info=info))
        report_progress(cfg, rows[-1])
    # the view from the sphere's centre: every camera ray must hit the inside (no
    # background pixel), lit by a light at the centre
    # (background magenta; black pixels are shadow acne of the ε offset, reported apart)
    inside = replace(scene, lights=[point_light(c, 1.0)],
                     cameras=[camera(c, c + [1.0, -0.3, 0.2], fov_y=120.0, size=128)],
                     settings=replace(scene.settings, background=np.array([1.0, 0.0, 1.0])))
    for prec in cfg.precisions:
        for routine in cfg.routines:
            img = render_image(inside, cfg, "bvh", routine, prec)
            bg = int(np.all(img == [1.0, 0.0, 1.0], axis=2).sum())
            acne = int((img.max(axis=2) == 0).sum())
            default = routine == DEFAULT_ROUTINE
            rows.append(Row(case="1 closed mesh", variant=f"bvh/{routine}/{prec} view",
                            criterion=("camera inside: 0 background pixels" if default
                                       else "background pixels reported (not default)"),
                            measured=(f"{bg} background pixels of {img.shape[0] * img.shape[1]}"
                                      f"; {acne} black (shadow acne of the ε offset)"),
                            passed=bg == 0 if default else True, value=float(bg),
                            image=save_image(cfg, f"closed_mesh_{routine}_{prec}", img)))
            report_progress(cfg, rows[-1])
    return rows


def _closed_mesh_counts(acc, t, cfg: Config, n, c, r, V, edges, zero_dirs, side) -> dict:
    """Misses per ray group of case 1 for one accelerator: {group: {misses, rays}}."""
    rng = np.random.default_rng(cfg.seed)
    fdt = np.float64 if t.is_double else np.float32
    V = V.astype(fdt).astype(np.float64)         # the vertices as the precision stores them

    def interior(k):
        """Interior points, rounded to the precision: a ray aimed at a vertex is then
        ``o`` exactly and ``d = v - o`` rounded once."""
        return (c + ball_points(rng, k) * (0.5 * r)).astype(fdt).astype(np.float64)

    def count(o, d):
        misses = 0
        for s0 in range(0, len(o), cfg.chunk):
            found, _, _ = closest_hit(acc, t, o[s0:s0 + cfg.chunk], d[s0:s0 + cfg.chunk])
            misses += int((~found).sum())
        return {"misses": misses, "rays": len(o)}

    info = {"random interior": {"misses": 0, "rays": 0}}
    left, batch = n, 0
    while left > 0:
        k = min(left, cfg.chunk)
        info["random interior"]["misses"] += device_interior_misses(acc, t, cfg, k, batch,
                                                                     c, r)
        info["random interior"]["rays"] += k
        left -= k
        batch += 1
    o = interior(len(V))
    info["at vertices"] = count(o, V - o)
    o = interior(len(edges))
    info["at edge midpoints"] = count(o, 0.5 * (V[edges[:, 0]] + V[edges[:, 1]]) - o)
    info["axis-aligned ±0"] = count(np.repeat(interior(64), len(zero_dirs), 0),
                                    np.tile(zero_dirs, (64, 1)))
    m = max(n // 10, 1000)
    pts = rng.uniform(-0.45 * side, 0.45 * side, size=(m, 2))
    targets = np.stack([pts[:, 0], np.zeros(m), pts[:, 1]], 1) + c + [0, -3 * r, 0]
    above = targets + np.concatenate([rng.uniform(-r, r, (m, 1)),
                                      rng.uniform(0.01 * r, r, (m, 1)),
                                      rng.uniform(-r, r, (m, 1))], 1)
    info["plane from above"] = count(above, targets - above)
    return info


# ---- case 2: re-intersection ---------------------------------------------------------------
def case_reintersect(cfg: Config, spec: dict) -> list[Row]:
    """Random triangles with coordinates log-uniform over 10^±range (random signs), each its
    own one-triangle scene (so its ε is that of a scene holding only it): a ray aimed at a
    random point of the triangle gives the hit ``p = o + t d`` (as the renderer computes
    it), from which ``rays_per_hit`` rays leave in random directions from
    ``spawn_origin``; none may hit the triangle again (criterion on the default routine, others
    reported). With one triangle every accelerator
    is the triangle routine itself, so the variants are routine x precision."""
    from renderer.accel.triangle import LAYOUT_VECTORS, layout_of, pack, triangle_routine
    nt, per, lr = int(spec["triangles"]), int(spec["rays_per_hit"]), float(spec["log10_range"])
    rows = []
    for prec in cfg.precisions:
        for routine in cfg.routines:
            rng = np.random.default_rng(cfg.seed)
            P = (10.0 ** rng.uniform(-lr, lr, size=(nt, 3, 3))) \
                * rng.choice([-1.0, 1.0], (nt, 3, 3))
            t = types(cfg.backend, prec)
            fdt = np.float64 if t.is_double else np.float32
            Pp = P.astype(fdt).astype(np.float64)        # the vertices the renderer sees
            layout = layout_of(routine)
            packed = pack(Pp.reshape(-1, 3), np.arange(3 * nt).reshape(nt, 3),
                          layout).astype(fdt).astype(np.float64)
            ng = np.cross(Pp[:, 1] - Pp[:, 0], Pp[:, 2] - Pp[:, 0])
            ok = np.linalg.norm(ng, axis=1) > 0
            ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
            diag = np.linalg.norm(Pp.max(1) - Pp.min(1), axis=1)
            eps = OVERRIDE_EPSILON * diag     # the explicit ray_epsilon override's rule
            b = rng.dirichlet([1, 1, 1], nt)
            aim = np.einsum("nk,nkj->nj", b, Pp)
            side = np.where(rng.uniform(size=(nt, 1)) < 0.5, 1.0, -1.0)
            dist = diag[:, None] * rng.uniform(0.5, 2.0, (nt, 1))
            org = aim + ng * side * dist + unit_vectors(rng, nt) * 0.1 * dist
            fn = triangle_routine(routine)

            def tri(idx, t=t, packed=packed, k=LAYOUT_VECTORS[layout]):
                return [array3(t, packed[idx, 3 * j:3 * j + 3]) for j in range(k)]
            o1, d1 = array3(t, org), array3(t, aim - org)
            th, _, _, h = fn(o1, d1, *tri(np.arange(nt)))
            p = dr.fma(d1, th, o1)
            dr.eval(p, h)
            hit = h.numpy() & ok
            src = np.flatnonzero(hit)
            pn = np.stack([c.numpy() for c in p], 1).astype(np.float64)[src]
            self_hits, n_rays = 0, 0
            step = max(cfg.chunk // per, 1)
            for s0 in range(0, len(src), step):
                idx = np.arange(s0, min(s0 + step, len(src)))
                reps = np.repeat(idx, per)
                dirs = unit_vectors(rng, len(reps))
                dd = array3(t, dirs)
                o2 = spawn_origin(array3(t, pn[reps]), array3(t, ng[src][reps]), dd,
                                  t.Float(eps[src][reps]))
                _, _, _, h2 = fn(o2, dd, *tri(src[reps]))
                self_hits += int(h2.numpy().sum())
                n_rays += len(reps)
            limit = int(spec["max_self_hits"])
            default = routine == DEFAULT_ROUTINE
            rows.append(Row(
                case="2 re-intersection", variant=f"{routine}/{prec}",
                criterion=(f"self-hits <= {limit}; >= 90 % of first rays hit" if default
                           else "self-hits reported (not default)"),
                measured=(f"{self_hits} self-hits in {n_rays} spawned rays "
                          f"({len(src)} of {nt} triangles hit by their first ray)"),
                passed=(self_hits <= limit and len(src) >= 0.9 * nt) if default else True,
                value=float(self_hits),
                info={"self_hits": self_hits, "rays": n_rays, "triangles_hit": len(src)}))
            report_progress(cfg, rows[-1])
    return rows


# ---- render helpers ------------------------------------------------------------------------
def render_image(scene: Scene, cfg: Config, accel="bvh", routine=None, prec="float32",
            effects=None) -> np.ndarray:
    from renderer.render import Renderer
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = Renderer(scene, backend=cfg.backend, precision=prec, accel=accel,
                     intersection=routine or DEFAULT_ROUTINE, effects=effects)
        return r.render(0).image


def save_image(cfg: Config, name: str, img: np.ndarray) -> str | None:
    """Write ``img`` (linear) as a PNG under ``cfg.out/images``; the relative path."""
    if cfg.out is None:
        return None
    from renderer.film import write_png
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)
    rel = f"images/{safe}.png"
    path = Path(cfg.out) / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, np.nan_to_num(img, nan=1.0, posinf=1.0, neginf=0.0), overwrite=True)
    return rel


def render_all(scene: Scene, cfg: Config, key: str, effects=None) -> dict:
    """Images of every variant (accel, routine, precision) of ``cfg``."""
    return {(a, r, p): render_image(scene, cfg, a, r, p, effects) for a, r, p in variants(cfg)}


def agree_rows(case: str, imgs: dict, cfg: Config, what: str) -> list[Row]:
    """Per (routine, precision): all pixels finite and every accelerator's image bitwise
    equal to brute force's (the oracle)."""
    rows = []
    for prec in cfg.precisions:
        for r in cfg.routines:
            group = {a: imgs[(a, r, prec)] for a in cfg.accels if (a, r, prec) in imgs}
            if not group:
                continue
            bad = sum(int((~np.isfinite(im)).sum()) for im in group.values())
            ref = group.get("brute", next(iter(group.values())))
            differ = [a for a, im in group.items() if not np.array_equal(im, ref)]
            rows.append(Row(case=case, variant=f"{'/'.join(group)}/{r}/{prec}",
                            criterion=f"{what}: all finite; accelerators bitwise equal",
                            measured=(f"{bad} non-finite values; "
                                      + (f"differ from brute: {differ}" if differ
                                         else "identical across accelerators")),
                            passed=bad == 0 and not differ, value=float(bad)))
            report_progress(cfg, rows[-1])
    return rows


def facing_light(scene: Scene, cfg: Config, routine: str, prec: str) -> np.ndarray:
    """(H, W) bool: the camera ray's hit has a geometric normal (turned to the viewer) that
    faces the scene's first light; False where the ray misses."""
    from renderer.camera import camera_arrays, primary_rays
    from renderer.render import Renderer
    r = Renderer(scene, backend=cfg.backend, precision=prec, intersection=routine)
    t, cam = r.t, scene.cameras[0]
    o, d = primary_rays(camera_arrays(cam, t), cam.width, cam.height, t)
    n = dr.width(d)
    hit = r.arrays.accel.intersect(Ray(o=o, d=d, t_max=t.Float(dr.inf)),
                                   dr.full(t.Bool, True, n))
    ng = dr.gather(t.Array3f, r.arrays.accel.tris.ng, hit.prim, hit.found)
    p = dr.fma(d, hit.t, o)
    ng = dr.select(dr.dot(ng, d) <= 0, ng, -ng)
    lit = hit.found & (dr.dot(ng, t.Array3f(*(float(x) for x in scene.lights[0].position)) - p) > 0)
    return lit.numpy().reshape(cam.height, cam.width)


def case_terminator(cfg: Config, spec: dict) -> list[Row]:
    """Low-polygon spheres with interpolated normals under grazing light. The sphere is
    convex and alone, so no shadow ray of it may be blocked where the shading says it is
    lit: every pixel that the render with shadows has darker (under half) than the render
    without is an artefact. Those where the hit's geometric normal faces the light are
    speckles (acne of the ray offsets): 0 in every variant and treatment. The others are
    the shadow terminator (the shading normal faces the light, the flat facet does not, so
    its shadow ray leaves into the sphere): counted without a treatment and with Hanika's
    (``Settings.terminator``); criterion for "hanika": at most ``max_hanika_share`` of the
    untreated count on the coarsest sphere and 0 on the finer ones."""
    from renderer.effects import EffectSet
    rows = []
    size = int(spec["size"])
    share = float(spec["max_hanika_share"])
    for prec in cfg.precisions:
        for r in cfg.routines:
            for sub in spec["subdivisions"]:
                counts = {}
                for fix in ("none", "hanika"):
                    term = speck = 0
                    lost_light, img = [], None
                    for ang in spec["angles"]:
                        sc = terminator_scene(int(sub), float(ang), size, fix)
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            off = render_image(sc, cfg, "bvh", r, prec,
                                          EffectSet.from_scene(sc).without("shadows"))
                        on = render_image(sc, cfg, "bvh", r, prec)
                        lost = (off.max(-1) > 0) & (on.max(-1) < 0.5 * off.max(-1))
                        facing = facing_light(sc, cfg, r, prec)
                        speck += int((lost & facing).sum())
                        term += int((lost & ~facing).sum())
                        lost_light.append(float((off - on).sum() / max(off.sum(), 1e-30)))
                        if ang == spec["angles"][0]:
                            img = save_image(cfg, f"terminator_{sub}_{fix}_{prec}", on)
                    counts[fix] = (term, speck, lost_light, img)
                base = counts["none"][0]
                for fix, (term, speck, lost_light, img) in counts.items():
                    if fix == "none":
                        crit, ok = "speckles (geometric normal faces the light) = 0", speck == 0
                    else:
                        lim = math.floor(share * base) if sub == min(spec["subdivisions"]) \
                            else 0
                        crit = f"speckles = 0; terminator pixels <= {lim}"
                        ok = speck == 0 and term <= lim
                    faces = 20 * 4 ** int(sub)
                    rows.append(Row(
                        case="7 shadow terminator",
                        variant=f"{faces} faces/{fix}/bvh/{r}/{prec}", criterion=crit,
                        measured=(f"terminator {term} px, speckles {speck} px over "
                                  f"{len(spec['angles'])} light angles; light lost "
                                  + "/".join(f"{x:.2%}" for x in lost_light)),
                        passed=bool(ok), value=float(term), image=img,
                        info={"terminator_px": term, "speckle_px": speck,
                              "lost_light": lost_light, "angles": list(spec["angles"])}))
                    report_progress(cfg, rows[-1])
    return rows


# ---- case 8: TIR at the critical angle ------------------------------------------------------
def case_tir(cfg: Config, spec: dict) -> list[Row]:
    """Rays leaving glass (ior 1.5, 2.4) at the critical angle ± 1..ulps ulp of its cosine:
    under TIR (the kernel's ``sin²t > 1``) no transmitted ray (``w_refr = 0`` exactly) and
    ``w_refl`` exactly as MODEL.md (constant: ``k_refl + k_refr``; Fresnel: ``k_refl · 1``);
    otherwise a finite unit T and the MODEL.md weights; no non-finite value anywhere."""
    from renderer.effects import EffectSet
    from renderer.shade import specular_branches, upload_materials
    rows = []
    ulps = int(spec["ulps"])
    for prec in cfg.precisions:
        t = types(cfg.backend, prec)
        fdt = np.float64 if t.is_double else np.float32
        for ior in spec["iors"]:
            cc = fdt(math.sqrt(1.0 - 1.0 / float(ior) ** 2))
            cos = [cc]
            for k in range(1, ulps + 1):
                up, dn = cc, cc
                for _ in range(k):
                    up, dn = np.nextafter(up, fdt(2)), np.nextafter(dn, fdt(-2))
                cos += [up, dn]
            cos = np.array(cos, fdt)
            sin = np.sqrt(fdt(1) - cos * cos)
            d = np.stack([sin, np.zeros_like(sin), cos], 1)       # leaving through +z
            n = len(d)
            for comb in ("constant", "fresnel"):
                mats = [material(k_refl=0.1, k_refr=0.9, ior=float(ior), combination=comb)]
                sc = mesh_scene([(np.eye(3), [[0, 1, 2]], 0)], mats)
                dm = upload_materials(sc, t)
                fx = EffectSet(reflection=True, refraction=True, fresnel=comb == "fresnel",
                               depth=1)
                ng = array3(t, np.tile([0.0, 0.0, 1.0], (n, 1)))
                sp = SurfacePoint(p=array3(t, np.zeros((n, 3))), ng=ng, ns=ng,
                                  material=t.UInt32(np.zeros(n, np.uint32)))
                br = specular_branches(sp, array3(t, d), dm, t, fx, dr.full(t.Bool, True, n))
                wr = np.stack([c.numpy() for c in br.w_refl], 1)
                wt = np.stack([c.numpy() for c in br.w_refr], 1)
                T = np.stack([c.numpy() for c in br.T], 1)
                # the kernel's TIR decision: sin²t = η² (1 - cos_i²) > 1, η = ior leaving
                eta = fdt(ior)
                ci = cos.astype(fdt)
                sin2 = (eta * eta * (fdt(1) - ci * ci)).astype(np.float64)
                tir = wt[:, 0] == 0
                finite = all(np.all(np.isfinite(x)) for x in (wr, wt, T))
                want_refl = 1.0 if comb == "constant" else 0.1
                ok_tir = np.all(wt[tir] == 0) and np.allclose(wr[tir], want_refl, rtol=0,
                                                               atol=0)
                ok_t = np.all(np.abs(np.linalg.norm(T[~tir], axis=1) - 1) < 1e-5)
                # exact classification on the rounded inputs, allowing the kernel's fma/
                # rounding to decide within 4 ulp of 1
                exact = float(ior) ** 2 * (1 - cos.astype(np.float64) ** 2)
                near = np.abs(exact - 1) <= 4 * np.finfo(fdt).eps
                agree = np.all(tir[~near] == (exact[~near] > 1))
                passed = finite and ok_tir and ok_t and agree and tir.any() and (~tir).any()
                rows.append(Row(
                    case="8 TIR critical angle", variant=f"ior {ior}/{comb}/{prec}",
                    criterion="TIR: w_refr = 0, w_refl per MODEL.md exactly; else unit T; "
                              "all finite",
                    measured=(f"{int(tir.sum())} of {n} directions (cos θc ± 1..{ulps} ulp) "
                              f"under TIR; finite {finite}; sin²t range "
                              f"[{sin2.min():.9g}, {sin2.max():.9g}]"),
                    passed=bool(passed), value=float(tir.sum())))
                report_progress(cfg, rows[-1])
    return rows


# ---- case 9: index-matched glass ---------------------------------------------------------
def case_index_matched(cfg: Config, spec: dict) -> list[Row]:
    """A glass sphere of ior 1 (k_refr = 1, nothing else) in a room equals the room without
    it wherever its shadow does not fall: shadow pixels are those where the render with
    shadows differs from the one without; elsewhere max |with - without| <= ``max_abs``."""
    from renderer.effects import EffectSet
    glass = material("glass", k_refr=1.0, ior=1.0)
    with_g = room_scene([sphere_object((0, 0.8, 0), 0.6, 2)], [glass])
    without = room_scene()
    rows = []
    lim = float(spec["max_abs"])
    for a, r, p in variants(cfg):
        fx = EffectSet.from_scene(with_g)
        A = render_image(without, cfg, a, r, p)
        B_on = render_image(with_g, cfg, a, r, p)
        with warnings.catch_warnings():      # "forced off" is the point here
            warnings.simplefilter("ignore")
            no_shadows = fx.without("shadows")
        B_off = render_image(with_g, cfg, a, r, p, effects=no_shadows)
        shadow = np.any(B_on != B_off, axis=2)
        diff = np.abs(B_on - A).max(axis=2)
        m = float(diff[~shadow].max()) if (~shadow).any() else 0.0
        img = save_image(cfg, f"index_matched_{a}_{r}_{p}", B_on) if a == "bvh" else None
        rows.append(Row(case="9 index-matched glass", variant=f"{a}/{r}/{p}",
                        criterion=f"max |with - without| <= {lim:g} outside shadows",
                        measured=(f"max abs {m:.3g} outside shadows "
                                  f"({int((diff[~shadow] > lim).sum())} pixels over; "
                                  f"{int(shadow.sum())} shadow pixels)"),
                        passed=m <= lim, value=m, image=img))
        report_progress(cfg, rows[-1])
    return rows


# ---- case 10: Phong extremes -------------------------------------------------------------
def case_phong(cfg: Config, spec: dict) -> list[Row]:
    """The local-light term of ``renderer.shade`` (one light per lane at unit distance,
    no shadows) over random direction pairs, including directions below the horizon, with
    kd + ks > 1 and exponents from 1e-3 to 1e4, against the MODEL.md formula evaluated in
    float64 on the same (rounded) inputs: all finite; float64 within ``max_rel`` absolute;
    float32 within ``max_rel`` plus the first-order effect of rounding R·V
    (``ks n rv^(n-1) · 8u``)."""
    from renderer.effects import EffectSet
    from renderer.lights import DeviceLights
    from renderer.shade import (
        SceneArrays,
        ShadingContext,
        TraceOptions,
        _light_term,
        phong_lobe,
        upload_materials,
    )
    rows = []
    N = int(spec["pairs"])
    tol = float(spec["max_rel"])
    kd, ks = 0.8, 0.7
    for prec in cfg.precisions:
        t = types(cfg.backend, prec)
        fdt = np.float64 if t.is_double else np.float32
        u = 2.0 ** -53 if t.is_double else 2.0 ** -24
        for mode in ("classic", "physical"):
            for n_exp in spec["exponents"]:
                rng = np.random.default_rng(cfg.seed)
                L = unit_vectors(rng, N).astype(fdt)
                V = unit_vectors(rng, N).astype(fdt)
                # half the pairs mirror L about the normal's axis so the lobe peak is hit
                k = N // 2
                Vm = np.stack([-L[:k, 0], -L[:k, 1], L[:k, 2]], 1)
                V[:k] = (Vm + rng.normal(scale=1e-3, size=(k, 3))).astype(fdt)
                V = (V / np.linalg.norm(V.astype(np.float64), axis=1, keepdims=True)
                     ).astype(fdt)
                sc = mesh_scene([(np.eye(3), [[0, 1, 2]], 0)],
                                [material(kd=kd, ks=ks, n=n_exp)],
                                settings=Settings(shading=mode))
                fx = EffectSet(specular=True, physical=mode == "physical")
                mats = upload_materials(sc, t)
                lights = DeviceLights(position=array3(t, L), intensity=array3(t, np.ones((N, 3))),
                                      inverse_square=t.Bool(np.full(N, mode == "physical")))
                sa = SceneArrays(accel=None, materials=mats, lights=lights)
                nrm = array3(t, np.tile([0.0, 0.0, 1.0], (N, 1)))
                sp = SurfacePoint(p=array3(t, np.zeros((N, 3))), ng=nrm, ns=nrm,
                                  material=t.UInt32(np.zeros(N, np.uint32)))
                Vd = array3(t, V)
                Nf = dr.select(dr.dot(Vd, nrm) >= 0, nrm, -nrm)
                ctx = ShadingContext(sp=sp, N=Nf, V=Vd, active=dr.full(t.Bool, True, N))
                lobe = phong_lobe(mats, ctx, t, fx)
                opt = TraceOptions(n_lights=N, max_depth=0, min_weight=0.0, eps=0.0)
                res = _light_term(t.UInt32(np.arange(N, dtype=np.uint32)), ctx, lobe, sa, t,
                                  fx, opt, dr.zeros(t.Array3f, N))
                got = res.x.numpy().astype(np.float64)
                # the formula, float64, on the rounded inputs
                L64, V64 = L.astype(np.float64), V.astype(np.float64)
                Lu = L64 / np.linalg.norm(L64, axis=1, keepdims=True)
                nz = np.where(V64[:, 2] >= 0, 1.0, -1.0)
                cos = Lu[:, 2] * nz
                R = np.stack([-Lu[:, 0], -Lu[:, 1], 2 * cos * nz - Lu[:, 2]], 1)
                rv = np.maximum((R * V64).sum(1), 0.0)
                with np.errstate(divide="ignore", under="ignore"):
                    spec_v = np.where(rv > 0, rv ** n_exp, 0.0)
                    grad = np.where(rv > 0, n_exp * rv ** max(n_exp - 1, 0.0), 0.0)
                if mode == "physical":
                    kd_e, ks_e = kd / np.pi, ks * (n_exp + 2) / (2 * np.pi)
                    want = kd_e * cos + ks_e * spec_v * cos
                    gb = ks_e * grad * np.abs(cos)
                else:
                    kd_e, ks_e = kd, ks
                    want = kd_e * cos + ks_e * spec_v
                    gb = ks_e * grad
                want = np.where(cos > 0, want, 0.0)
                bound = tol + (0.0 if t.is_double else 8 * u * gb + 8 * u * np.abs(want))
                err = np.abs(got - want)
                finite = bool(np.all(np.isfinite(got)))
                over = int((err > bound).sum())
                rows.append(Row(
                    case="10 Phong extremes", variant=f"n={n_exp:g}/{mode}/{prec}",
                    criterion=("|ours - formula| <= 1e-5" if t.is_double else
                               "|ours - formula| <= 1e-5 + first-order float32 rounding"),
                    measured=(f"max err {err.max():.3g}, {over} of {N} pairs over; "
                              f"finite {finite}; {int((cos <= 0).sum())} below horizon"),
                    passed=finite and over == 0, value=float(err.max())))
                report_progress(cfg, rows[-1])
    return rows


def case_degenerate(cfg: Config, spec: dict) -> list[Row]:
    """``degenerate_scene``: every pixel finite, no crash, accelerators agree."""
    sc = degenerate_scene()
    imgs = render_all(sc, cfg, "degenerate")
    rows = agree_rows("11 degenerate input", imgs, cfg, "zero-area/collinear/duplicate, "
                       "edge-on boxes")
    if cfg.out is not None and rows:
        rows[0].image = save_image(cfg, "degenerate", imgs[next(iter(imgs))])
    return rows


def case_robust_scenes(cfg: Config, spec: dict) -> list[Row]:
    """Camera inside glass, light inside a closed box (no light may leak out: the image
    equals the render without the light), coplanar overlapping faces (every pixel of the
    overlap shows the lower face index: no speckle), hall of mirrors at max depth 16;
    for all: finite, accelerators bitwise equal, and a repeat render bitwise identical."""
    rows = []
    for name, sc in robust_scenes().items():
        imgs = render_all(sc, cfg, name)
        rows += agree_rows(f"12 {name}", imgs, cfg, name)
        key = next(iter(imgs))
        again = render_image(sc, cfg, *key)
        same = np.array_equal(again, imgs[key])
        rows.append(Row(case=f"12 {name}", variant="/".join(key),
                        criterion="repeat render bitwise identical",
                        measured="identical" if same else "differs", passed=same,
                        image=save_image(cfg, name.replace(" ", "_"), imgs[key])))
        report_progress(cfg, rows[-1])
        if name == "light in a closed box":
            dark = replace(sc, lights=[point_light((0, 0.8, 0), 0.0)])
            for key, im in imgs.items():
                ref = render_image(dark, cfg, *key)
                leak = int((np.abs(im - ref).max(axis=2) > 0).sum())
                rows.append(Row(case="12 light in a closed box", variant="/".join(key),
                                criterion="no light leaks: image == image without the light",
                                measured=f"{leak} lit pixels", passed=leak == 0,
                                value=float(leak)))
                report_progress(cfg, rows[-1])
        if name.startswith("coplanar"):
            same = name == "coplanar overlapping faces"
            for key, im in imgs.items():
                green = int(((im[..., 1] > im[..., 0]) & (im[..., 1] > im[..., 2])).sum())
                # duplicated faces tie in every routine; other vertices on the same
                # axis-aligned plane tie where t is the plane's (the watertight routine)
                judged = same or key[1] == DEFAULT_ROUTINE
                rows.append(Row(
                    case=f"12 {name}", variant="/".join(key),
                    criterion=("ties go to the lower face index (red): 0 green" if judged
                               else "speckle reported (not default: t rounds per triangle)"),
                    measured=f"{green} green pixels", passed=green == 0 if judged else True,
                    value=float(green)))
                report_progress(cfg, rows[-1])
    return rows


# ---- case 13: float32 vs float64 ----------------------------------------------------------
def case_precision(cfg: Config, spec: dict) -> list[Row]:
    """Every render case in float32 and float64 (BVH, each routine): the largest pixel
    difference is reported and bounded by ``max_abs`` (coplanar faces without exact ties
    are only reported: there rounding legitimately picks the visible face)."""
    if not {"float32", "float64"} <= set(cfg.precisions):
        return []
    lim = float(spec["max_abs"])
    scenes = {"index-matched glass": room_scene([sphere_object((0, 0.8, 0), 0.6, 2)],
                                           [material("glass", k_refr=1.0, ior=1.0)]),
              "degenerate": degenerate_scene(), **robust_scenes()}
    rows = []
    for name, sc in scenes.items():
        for r in cfg.routines:
            a32 = render_image(sc, cfg, "bvh", r, "float32")
            a64 = render_image(sc, cfg, "bvh", r, "float64")
            d = np.abs(a32 - a64).max(axis=2)
            frac = float((d > 1e-3).mean())
            # Möller–Trumbore's t rounds per triangle: coplanar faces z-fight there
            zfight = name == "coplanar faces, other vertices" and r != DEFAULT_ROUTINE
            rows.append(Row(case="13 float32 vs float64", variant=f"{name}/bvh/{r}",
                            criterion=("reported (coplanar faces without exact ties: "
                                       "rounding picks the face)" if zfight else
                                       f"max abs difference <= {lim:g}"),
                            measured=f"max abs {d.max():.3g}; {frac:.4%} of pixels > 1e-3",
                            passed=True if zfight else float(d.max()) <= lim,
                            value=float(d.max())))
            report_progress(cfg, rows[-1])
    return rows


def case_mitsuba_parity(cfg: Config, spec: dict) -> list[Row]:
    """Ours against Mitsuba 3 with Embree fast (its default) and robust
    (``embree_use_robust_intersections``), on LLVM in float32. Rays: case 1's closed mesh far
    from the origin, rays aimed exactly at its vertices and edge midpoints
    (``vertex_repeats``/``edge_repeats`` interior origins each) and random interior rays:
    misses of ours (BVH, default routine) and of robust Embree must be 0; fast Embree's are
    reported (it is not watertight). Renders: ``parity_scenes``, ours with ``spawn =
    "mitsuba"`` (so both trace the same rays) against Mitsuba's exact-mode ``whitted``
    render in each Embree mode; pixels over 1e-3 apart are counted and those not explained
    as ties on shared edges (``evaluation.gate.agreement.edge_mask``) must number 0 against robust
    Embree, but in ``PARITY_TIES_BY_DESIGN`` (reported)."""
    if cfg.backend != "llvm" or "float32" not in cfg.precisions:
        return []
    from evaluation.gate.agreement import TOL, edge_mask
    from reference import mitsuba_variant
    from reference.robust import closest_t, render_exact_mode
    from renderer.render import render
    mitsuba_variant("llvm_ad_rgb")
    rows = []
    closed = load_cases()["closed_mesh"]
    V, F, c, r, sc = closed_mesh_scene(closed)
    V32 = V.astype(np.float32).astype(np.float64)
    edges = mesh_edges(F)
    rng = np.random.default_rng(cfg.seed)

    def interior(k):
        return (c + ball_points(rng, k) * (0.5 * r)).astype(np.float32).astype(np.float64)

    groups = {}
    k = int(spec["vertex_repeats"])
    o = interior(len(V) * k)
    groups["at vertices"] = (o, np.tile(V32, (k, 1)) - o)
    k = int(spec["edge_repeats"])
    o = interior(len(edges) * k)
    groups["at edge midpoints"] = (o, np.tile(0.5 * (V32[edges[:, 0]] + V32[edges[:, 1]]),
                                              (k, 1)) - o)
    m = int(spec["random_rays"])
    groups["random interior"] = (interior(m), unit_vectors(rng, m))
    t = types("llvm", "float32")
    acc = build_accelerator("bvh", sc, t)
    for g, (o, d) in groups.items():
        ours = int((~closest_hit(acc, t, o, d)[0]).sum())
        fast, robust = (int((~np.isfinite(closest_t(sc.vertices, sc.faces, o, d,
                                                     robust=rb))).sum())
                        for rb in (False, True))
        rows.append(Row(case="14 Mitsuba parity", variant=f"closed mesh rays {g}",
                        criterion="misses: ours 0, Embree robust 0 (Embree fast reported)",
                        measured=(f"of {len(o)} rays: ours {ours}, Embree robust {robust}, "
                                  f"Embree fast {fast} misses"),
                        passed=ours == 0 and robust == 0, value=float(fast),
                        info={"rays": len(o), "ours": ours, "robust": robust, "fast": fast}))
        report_progress(cfg, rows[-1])

    def differ(a, b):
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        over = ~(np.abs(a - b).max(-1) <= TOL)
        return int(over.sum()), int((over & ~edge_mask(a, b, TOL)).sum())

    for name, scene in parity_scenes(closed, int(spec["size"])).items():
        ours = render(scene.with_settings(spawn="mitsuba"), backend="llvm").image
        fast = render_exact_mode(scene, robust=False)
        robust = render_exact_mode(scene, robust=True)
        vs_r, vs_f, f_r = differ(ours, robust), differ(ours, fast), differ(fast, robust)
        by_design = name in PARITY_TIES_BY_DESIGN
        tie, tie_info = "", {}
        if by_design:      # the overlap: red (face 2, the lower index) or green (face 3)
            def green(im):
                return (im[..., 1] > im[..., 0]) & (im[..., 1] > im[..., 2])
            over = ~(np.abs(ours - robust).max(-1) <= TOL)
            tie_info = {"embree_green_ours_red": int((over & green(robust) & ~green(ours)).sum()),
                        "ours_green": int((over & green(ours)).sum())}
            tie = (f"; of those vs robust, {int((over & green(robust) & ~green(ours)).sum())}"
                   f" green in Embree where ours is red (tie to the lower face), "
                   f"{int((over & green(ours)).sum())} green in ours")
        rows.append(Row(
            case="14 Mitsuba parity", variant=f"{name}/spawn mitsuba/bvh/float32",
            criterion=("reported: coplanar ties by design (ours: plane t, lowest face; "
                       "Embree: t rounded per triangle)" if by_design else
                       "vs Embree robust: 0 pixels > 1e-3 that are not edge ties"),
            measured=(f"pixels > 1e-3 (not edge ties): vs robust {vs_r[0]} ({vs_r[1]}), "
                      f"vs fast {vs_f[0]} ({vs_f[1]}), fast vs robust {f_r[0]} ({f_r[1]}) "
                      f"of {ours.shape[0] * ours.shape[1]}{tie}"),
            passed=True if by_design else vs_r[1] == 0, value=float(vs_r[1]),
            image=save_image(cfg, f"parity_{name.replace(' ', '_')}_mitsuba_robust", robust),
            info={"vs_robust": vs_r, "vs_fast": vs_f, "fast_vs_robust": f_r, **tie_info}))
        report_progress(cfg, rows[-1])
    return rows


def report_progress(cfg: Config, row: Row) -> None:
    if cfg.progress:
        mark = "ok " if row.passed else "RED"
        print(f"[{mark}] {row.case} | {row.variant} | {row.measured}", file=sys.stderr,
              flush=True)


# ---- case 15: far origins ----------------------------------------------------------------
def case_far_origin(cfg: Config, spec: dict) -> list[Row]:
    """Rays from far away (``distances``: 10^3..10^6 sphere radii; about three quarters of
    them start beyond the scene's reach, the largest coordinate of its camera, lights and
    vertices plus its size, the rest within it), aimed at the vertices and edge midpoints of
    an icosphere far from the origin (the faces of its leaf boxes) and at random points of it:
    every accelerator must give brute force's hits, closest (found, face, and t bitwise
    where found) and any. Boxes are padded for the origins within the scene's reach; rays
    from farther away enter every box (``renderer.accel.traverse.box_ray``). Counted per
    (accel, routine, precision): rays whose answer differs from brute force's, 0 for
    every routine (agreement is the accelerators' property, whichever test they share).
    Dr.Jit's ``dr.rcp`` of float64 is ``rcp.approx`` on CUDA, whose distances fall short
    of the padded boxes' reach (a BVH then culls the nearer hit at vertex rays);
    ``renderer.device.rcp`` divides instead."""
    c = np.asarray(spec["center"], np.float64)
    r = float(spec["radius"])
    V, F = shapes.make_shape("sphere", subdivisions=int(spec["subdivisions"]))
    V = V * r + c
    scene = mesh_scene([(V, F, 0)], [material(kd=0.5)],
                       camera=camera(c + [0, 0, 4 * r], c))
    rng = np.random.default_rng(cfg.seed)
    edges = mesh_edges(F)
    k = int(spec["random_rays"])
    u, w = rng.uniform(size=(2, k))
    tri = F[rng.integers(0, len(F), k)]
    su = np.sqrt(u)[:, None]
    surf = (V[tri[:, 0]] * (1 - su) + V[tri[:, 1]] * (su * (1 - w[:, None]))
            + V[tri[:, 2]] * (su * w[:, None]))
    groups = {"at vertices": V, "at edge midpoints": 0.5 * (V[edges[:, 0]] + V[edges[:, 1]]),
              "random": surf}
    lo, hi = (math.log10(x) for x in spec["distances"])
    rays = {}
    for g, targets in groups.items():
        dist = r * 10.0 ** rng.uniform(lo, hi, (len(targets), 1))
        o = targets + unit_vectors(rng, len(targets)) * dist
        rays[g] = (o, targets - o)
    rows = []
    for prec in cfg.precisions:
        t = types(cfg.backend, prec)
        for routine in cfg.routines:
            ref = {g: ray_answers(build_accelerator("brute", scene, t, intersection=routine),
                               t, o, d) for g, (o, d) in rays.items()}
            for accel in cfg.accels:
                if accel == "brute":
                    continue
                acc = build_accelerator(accel, scene, t, intersection=routine)
                info = {}
                for g, (o, d) in rays.items():
                    got, want = ray_answers(acc, t, o, d), ref[g]
                    f = want[0]
                    bad = ((got[0] != f) | (got[3] != want[3])
                           | (f & ((got[1] != want[1]) | (got[2] != want[2]))))
                    info[g] = {"differ": int(bad.sum()), "rays": len(o), "hits": int(f.sum())}
                differ = sum(v["differ"] for v in info.values())
                total = sum(v["rays"] for v in info.values())
                rows.append(Row(
                    case="15 far origins", variant=f"{accel}/{routine}/{prec}",
                    criterion="= brute force: 0 rays differ",
                    measured=(f"{differ} of {total} rays differ from brute force ("
                              + ", ".join(f"{g}: {v['differ']}/{v['rays']}"
                                          for g, v in info.items()) + ")"),
                    passed=differ == 0, value=float(differ),
                    info=info))
                report_progress(cfg, rows[-1])
    return rows


# ---- the suite -------------------------------------------------------------------------------
#: Case functions by their table name in ``cases.toml``.
CASES = {"closed_mesh": case_closed_mesh, "reintersect": case_reintersect,
         "terminator": case_terminator, "tir": case_tir,
         "index_matched": case_index_matched, "phong": case_phong,
         "degenerate": case_degenerate, "robust_scenes": case_robust_scenes,
         "precision": case_precision, "mitsuba_parity": case_mitsuba_parity,
         "far_origin": case_far_origin, "far_snapped": case_far_snapped}


def run_suite(cfg: Config, names=None, table: dict | None = None) -> list[Row]:
    """Rows of the cases ``names`` (default: all of ``CASES``) under ``cfg``."""
    table = load_cases() if table is None else table
    names = list(CASES) if names is None else list(names)
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise ValueError(f"cases: unknown {unknown}; expected some of {list(CASES)}")
    rows = []
    for name in names:
        rows += CASES[name](cfg, table[name])
    return rows
