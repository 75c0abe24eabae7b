"""The distributed swarm: processes, networking, learning, studies and the CLI.

Importing it sets one BLAS thread per process unless the environment already chose: numpy's
OpenBLAS otherwise starts a worker per core that spin-waits between calls, so two processes on
this 2-core machine (two trainings side by side, training workers, a robot beside the world)
spend half the CPU spinning (measured: each trainer's spare thread at ~50% of a core, training
4-8x slower). Our matrices are small; one thread is what each process should use. This has to
run before numpy is imported, which is why it is here, at the top of the package every entry
point imports first. torch's pool is set per process with `torch.set_num_threads`.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
