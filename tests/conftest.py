import os

# Keep thread pools small: CI machines have 2 cores and tests run Blender subprocesses too.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
