"""The checks of the rules: does the gate catch what it should and pass what it should?

``mutation`` (planted bugs against the tests: the mutation score), ``null_test`` (the
converged rule's false-failure rate on two renders of ours), ``tie_count`` (the pixels the
exact rule excuses per case) and ``speckles`` (the Mitsuba reference on CUDA against LLVM,
per way of spawning rays).
"""
