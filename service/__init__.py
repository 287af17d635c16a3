"""The service around the simulator: study files and runs, the API, the nightly suite, the client.

``worker`` is imported first, whichever part of the service a process enters by (the CLI, the
API app under any server, the runner used as a library): it pins the CPU target before numpy and
numba load, so the process and the workers it starts compute the same bits as every other
x86-64 machine with AVX2 (worker/cpu.py).
"""

import worker  # noqa: F401
