"""A Whitted ray tracer on Dr.Jit (CUDA on NVIDIA GPUs, LLVM on CPUs).

This package never imports ``mitsuba`` or ``reference``.
"""
