"""The fair Mitsuba peer (reference.peer): same image as ours and as the harness's
integrator, one kernel per frame, and freezing changes nothing."""
from __future__ import annotations

from pathlib import Path

import drjit as dr
import numpy as np

from evaluation.bench.peer import deepest, peer_compiles, peer_note, plan, whitted_frame_peer
from evaluation.bench.peer import markdown as peer_markdown
from evaluation.gate.rules import EXACT_THRESHOLDS, check_exact
from reference import mitsuba_variant
from reference.mitsuba_scene import render_exact
from reference.peer import load_peer
from renderer.render import Renderer
from renderer.scene import load_scene
from renderer.stats import kernel_launches

ROOT = Path(__file__).resolve().parent.parent
#: One process renders with one Mitsuba variant: the one the harness picks (LLVM on CI).
VARIANT = mitsuba_variant()
BACKEND = "cuda" if VARIANT.startswith("cuda") else "llvm"


def _scene(name: str, depth: int, size: int):
    return (load_scene(ROOT / "scenes" / f"{name}.toml")
            .with_settings(max_depth=depth, exact=True).with_size(size))


def _jit_kernels(fn) -> int:
    _, hist, _ = kernel_launches(fn)
    return sum(1 for h in hist if h.get("type") == dr.KernelType.JIT)


def test_peer_agrees_with_ours_at_depth_2():
    # the peer spawns rays with the fixed offset rule (1e-4 x diagonal along N_g); ours takes
    # the same rule through the explicit ray_epsilon override, so only arithmetic differs
    sc = _scene("platonic_solids", 2, 32).with_settings(ray_epsilon=1e-4)
    ours = Renderer(sc, backend=BACKEND, accel="bvh", exact=True).render().image
    peer = load_peer(sc, backend=BACKEND)
    img = peer.frame().numpy()
    res = check_exact(img, ours, EXACT_THRESHOLDS)
    assert res["ok"], res
    assert np.mean(np.abs(img - ours).max(-1) <= 1e-3) == 1.0


def test_peer_equals_the_harness_integrator():
    """Same model, same Mitsuba calls: the one-kernel peer gives the wavefront harness
    integrator's pixels bit for bit (reflection, two lights)."""
    peer = load_peer(_scene("cornell_box", 2, 24), backend=BACKEND)
    assert np.array_equal(peer.frame().numpy(), render_exact(peer.scene))


def test_peer_frame_is_one_kernel():
    peer = load_peer(_scene("cornell_box", 2, 16), backend=BACKEND)
    pos = peer.positions()
    assert _jit_kernels(lambda: peer.frame(pos)) == 1


def test_frozen_peer_equals_traced():
    """Glass (reflection and refraction children, dielectric and conductor virtual calls):
    one kernel traced, one frozen, the same pixels."""
    peer = load_peer(_scene("glass_bunny", 2, 16), backend=BACKEND)
    pos = peer.positions()
    assert _jit_kernels(lambda: peer.frame(pos)) == 1
    traced = peer.frame(pos).numpy()
    run = peer.frozen()
    first = run(pos).numpy()      # recording
    again = run(pos).numpy()      # replay
    assert np.array_equal(traced, first) and np.array_equal(traced, again)
    assert _jit_kernels(lambda: run(pos)) == 1


def _soft(samples: int, size: int = 16):
    return (load_scene(ROOT / "scenes" / "cornell_soft.toml")
            .with_overrides(shadow_samples=samples, max_depth=1, size=(size, size)))


def _ops(fn) -> int:
    _, hist, _ = kernel_launches(fn)
    return sum(int(h.get("operation_count", 0)) for h in hist
               if h.get("type") == dr.KernelType.JIT)


def test_soft_peer_kernel_does_not_grow_with_shadow_samples():
    """The shadow samples of a sphere light are one symbolic loop: 64 samples compile to the kernel
    of 4 (an unrolled Python loop grows it 16-fold and takes minutes on CUDA)."""
    ops = []
    for n in (4, 64):
        peer = load_peer(_soft(n, 8), backend=BACKEND)
        pos = peer.positions()
        def frame(peer=peer, pos=pos):
            return peer.frame(pos)
        assert _jit_kernels(frame) == 1
        ops.append(_ops(frame))
    assert ops[1] == ops[0], ops


def test_soft_peer_samples_are_stratified_as_ours():
    """Like for like: at 16 shadow samples the peer's noise (rms against its own 1024-sample
    image) is ours (rms against our 1024-sample image), not the ~2x of independent samples,
    and the converged images agree."""
    def ours(n):
        sc = _soft(n)
        r = Renderer(sc, backend=BACKEND)
        return r.frame(r.camera(0), 16, 16).numpy()

    def peer(n):
        return load_peer(_soft(n), backend=BACKEND).frame().numpy()

    o_ref, p_ref = ours(1024), peer(1024)
    rms_o = np.sqrt(np.mean((ours(16) - o_ref) ** 2))
    rms_p = np.sqrt(np.mean((peer(16) - p_ref) ** 2))
    assert 0.75 < rms_p / rms_o < 1.33, (rms_p, rms_o)
    close = np.abs(p_ref - o_ref).max(-1) < 0.01      # all but the box's creases
    assert close.mean() > 0.9
    assert abs(p_ref[close].mean() / o_ref[close].mean() - 1) < 2e-3


def test_whitted_frame_peer_row():
    r = whitted_frame_peer(load_scene(ROOT / "scenes" / "platonic_solids.toml"),
                           backend=BACKEND, depth=1, size=16, frames=2)
    assert r["peer_kernels"] == 1 and r["peer_frozen_equals_traced"]
    assert r["difference"]["exact_ok"] and r["ours_frozen_ms"] > 0 and r["peer_frozen_ms"] > 0


def test_compile_probe_reports_a_compile_and_a_timeout():
    """The probe subprocess renders a peer frame and reports it; one that runs past its
    timeout is killed and reported as not compiling."""
    path = ROOT / "scenes" / "cornell_box.toml"
    ok = peer_compiles(path, 1, 300.0, backend=BACKEND, size=8)
    assert ok["compiles"] and ok["error"] is None and ok["operations"] > 0, ok
    late = peer_compiles(path, 1, 0.2, backend=BACKEND, size=8)
    assert not late["compiles"] and late["error"] == "timeout after 0.2 s"


def test_deepest_compiling_depth_and_the_note_beside_ours():
    probes = [{"depth": 3, "compiles": True}, {"depth": 5, "compiles": False,
                                                "error": "timeout after 45 s"},
              {"depth": 4, "compiles": True}]
    assert deepest(probes) == 4
    assert peer_note(probes) == "does not compile at depth 5 (timeout after 45 s)"
    assert deepest(probes[:1]) == 3 and peer_note(probes[:1]) == "not probed above depth 3"
    assert deepest([dict(probes[1], depth=3)]) == 2


def test_peer_markdown_shows_ours_alone_where_the_peer_does_not_compile():
    ours_only = {"kind": "frame", "scene": "cornell_box", "depth": 5, "size": 64,
                 "ours_frozen_ms": 1.0, "ours_kernel_ms": 0.5,
                 "peer_note": "does not compile at depth 4 (timeout after 45 s)"}
    probe = {"kind": "probe", "scene": "cornell_box", "depth": 4, "compiles": False,
             "seconds": 45.0, "error": "timeout after 45 s"}
    text = "\n".join(peer_markdown([ours_only, probe]))
    assert "| cornell_box | 5 | 64² | 1.000 | 0.500 | does not compile at depth 4" in text
    assert "| cornell_box | 4 | no: timeout after 45 s | 45.0 | — |" in text


def test_plan_caps_the_compile_probes_on_cuda():
    """On CUDA (OptiX does not compile depth 5 within 8 minutes) the probes are depths 3-5,
    45 s each, all at once, so the part fits a 5-minute GPU job; quick runs probe depth 3."""
    from evaluation.bench.part import Context
    cuda = plan(Context("cuda", ROOT / "scenes", ROOT), 4)
    assert (cuda.sizes, cuda.probe_depths, cuda.probe_timeout_s) == ((512, 1024), (3, 4, 5), 45)
    assert cuda.probe_jobs >= 12 and cuda.deep_size == 1024
    quick = plan(Context("llvm", ROOT / "scenes", ROOT, quick=True), 4)
    assert quick.sizes == (128, 256) and quick.probe_depths == (3,) and quick.frames == 5
