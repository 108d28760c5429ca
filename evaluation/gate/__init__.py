"""The gate: where a verdict is made. Our image against its Mitsuba golden, per case.

``rules`` (the golden regression cases as data, each with its comparison rule and
thresholds: the exact rule with its tie probe, the converged t-test over our own batches),
``metrics`` (image differences and the statistical test), ``verdict`` (verdicts, JUnit/JSON;
``exit_codes``: the exit code of each status), ``report`` (the side-by-side HTML report),
``agreement`` (ours against a golden folder, per exact case), ``executor`` (in-process or
Dask workers, for the goldens and the study) and ``pytest_plugin`` (the ``pytest11``
plugin: one test per scene view).
"""
