"""How the per-sample kernels are compiled: numba, IEEE float semantics, cached on disk.

Step 2 on a tick of a few dozen whiskers is a few hundred flops per sample: as numpy array
code its cost would be the calls, not the arithmetic, so it is a scalar function per sample,
compiled, and each sample is computed on its own (the same bits whatever the other samples of
the call). Figures in docs/PERFORMANCE.md.

``error_model="numpy"``: a division by zero gives inf or NaN, as in numpy (the kernels flag such
samples), instead of raising. ``cache=True``: the machine code is written next to the module
(``__pycache__``, or numba's user cache where that is read-only), so a process compiles a
kernel once per installation, not at every start.
"""

from numba import njit

compiled = njit(cache=True, error_model="numpy")
