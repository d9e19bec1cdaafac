"""stereo-bench: hardware-in-the-loop stereo measurement of a checkerboard square."""

import os
from importlib.metadata import PackageNotFoundError, version

# OpenBLAS (numpy's, and the LAPACK in OpenCV 5's wheels) keeps its idle worker threads spinning for
# 2^28 cycles after every threaded call. On the 2 cores of a bench, where our own pools (capture,
# decoding, detection, analysis) use every core, that spinning took 2-6 ms of CPU per replayed stereo
# pair (scripts/results/bench_replay.json). 2^4 cycles: the workers sleep at once and are woken for the
# next call. How the work is split (the thread count) is untouched, so every number stays the same to
# the last digit (a replay stays identical). OpenBLAS reads this when it loads, at the first import of
# numpy or cv2, which this package imports only after this line; a value the user set is kept.
os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")

try:
    __version__ = version("stereo-bench")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+source"
