"""mocap-index: find similar motion-capture clips, and the moments inside long takes."""

import os

# One thread for numpy's OpenBLAS and FAISS's OpenMP in every process. Each reads
# OMP_NUM_THREADS once, when it loads, so it is set here, before either is first imported
# (every entry point imports the package first: the CLI, uvicorn's factory, the tests); a
# value the operator set is kept. A search's matrix products are small and a single query is
# not faster on more threads (STYLE.md); two BLAS threads in each worker only contended with
# the other workers and requests (bench/README.md, moments at 100 h: median 0.94x with one).
os.environ.setdefault("OMP_NUM_THREADS", "1")
