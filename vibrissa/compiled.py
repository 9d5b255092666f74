"""How the per-sample kernels are compiled: numba, IEEE float semantics, cached on disk.

Step 2 on a tick of a few dozen whiskers is a few hundred flops per sample: as numpy array
code its cost would be the calls, not the arithmetic, so it is a scalar function per sample,
compiled, and each sample is computed on its own (the same bits whatever the other samples of
the call). Figures in docs/PERFORMANCE.md.

``error_model="numpy"``: a division by zero gives inf or NaN, as in numpy (the kernels flag such
samples), instead of raising. ``cache=True``: the machine code is written next to the module
(``__pycache__``, or numba's user cache where that is read-only), so a process compiles a
kernel once per installation, not at every start.

``inlined``: the same, and inlined into its compiled callers by numba (``inline="always"``),
for the functions of one row that a row loop calls with views of its arrays. A call with
array arguments is not inlined by LLVM and costs more than its arithmetic (Step 2's row: 0.49
us inlined, 0.73 us called; `benchmarks/bench_tick_cpu.py`); the bits are the same (no
fast-math: IEEE operations in the same order).
"""

from numba import njit

compiled = njit(cache=True, error_model="numpy")
inlined = njit(cache=True, error_model="numpy", inline="always")
