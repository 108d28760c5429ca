"""What accuracy costs in time: the accuracy-vs-time study.

Per scene, one factor at a time around a default setting, plus the spp × depth grid:

======================  ==============================================================
factor                  values
======================  ==============================================================
``spp``                 samples per pixel (stratified jitter): 1, 4, 16, 64, 256
``max_depth``           0 … 8
``min_weight``          weight cut-off: 0, 0.001, 0.01, 0.1
``precision``           float32, float64
``combination``         constant, fresnel (a model change: plotted apart, off the front)
``intersection``        every routine of the triangle-routine registry
``accel``               every accelerator of the registry (brute, boxes, bvh): same image
``effects``             auto (the scene's effect set) vs all (the general kernel)
``shadow_samples``      shadow rays per light with extent: 1, 4, 16, 64 (only scenes with a
                        sphere or rectangle light)
``grid``                spp × max_depth
======================  ==============================================================

The default of each scene is its own file's ``max_depth``, ``min_weight`` and combination,
float32, the first triangle routine, the BVH, auto effects and ``Profile.default_spp``.

Every point is rendered in converged mode (stratified jitter, ``spp`` samples per pixel) with
``len(seeds)`` seeds (>= 5), and each image is compared against two references:

- ``golden``: the converged Mitsuba golden of the scene (``reference/goldens``, 128 × 128,
  box-averaged when the study runs at a divisor of that size);
- ``own``: our own render of the scene's *default* setting at ``Profile.ref_spp`` (same model
  variant, i.e. the same ``combination``), so error against ``own`` is our sampling error
  plus what the factor changes, and error against ``golden`` adds the model difference to
  Mitsuba.

Metrics per image (``error_metrics``): RMSE, relMSE (``(a-r)^2 / (r^2 + eps)``, eps 0.01)
and relMSE trimmed at 0.1 % (the worst 0.1 % of pixels dropped), mean and 95th percentile
HDR-FLIP, mean CIEDE2000 (only where colour-science is installed; else skipped with a note in
the results). A point stores the per-seed values and mean / std / min / max.

Time per point (one seed): the first traced frame's wall time with Dr.Jit's compile time
(codegen + backend, from the kernel history) reported apart; then the frame wrapped in
``dr.freeze`` (as ``Renderer(freeze=True)`` does), recorded once and replayed: kernel time
(median of the kernel history's ``execution_time`` over repeats after warm-up) and frozen
frame wall time. Device, backend and versions go with every point.

The package's modules are its phases: ``points`` (the plan: profiles, factors, the
sweep), ``run`` (rendering and measuring the points, resumable, in-process or on Dask
workers), ``report`` (markdown, plots, HTML) and ``readme`` (the README block).

Points run through ``evaluation.gate.executor`` (in-process, or Dask workers); the results
JSON
is rewritten (temp file + rename) after every point, so a run can stop anywhere and
resume.
``write_outputs`` turns the JSON into markdown, PNG + SVG plots and an HTML page.
"""
from __future__ import annotations

from .points import (
    FACTORS,
    METRICS,
    PROFILES,
    REFS,
    SEED_SCENES,
    build_sweep,
    prepare_scene,
)
from .readme import (
    readme_marker,
    readme_section,
    update_readme,
)
from .report import (
    equal_time_rows,
    err_of,
    factor_line,
    factor_sentences,
    markdown,
    pareto,
    scene_points,
    summary_sentences,
    time_of,
    write_outputs,
)
from .run import (
    StudyFileError,
    block_mean,
    error_metrics,
    executor_check,
    golden_for,
    load_results,
    metrics_available,
    render_seeds,
    run_study,
    strip_timings,
)

__all__ = [
    "FACTORS", "METRICS", "PROFILES", "REFS", "SEED_SCENES", "block_mean", "build_sweep",
    "equal_time_rows", "err_of", "error_metrics", "executor_check", "factor_line",
    "factor_sentences", "golden_for", "load_results", "StudyFileError", "markdown",
    "metrics_available",
    "pareto", "prepare_scene", "readme_marker", "readme_section", "render_seeds", "run_study",
    "scene_points", "strip_timings", "summary_sentences", "time_of", "update_readme",
    "write_outputs"
]
