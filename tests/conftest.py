"""Test-wide setup."""

import os

# The kernels and references are small dense problems: a multi-threaded BLAS only contends with
# the dask worker processes on a 2-core machine (scipy's expm ran 40x slower under load with it).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
