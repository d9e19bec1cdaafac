import sys

from stereo_bench.cli import main

sys.exit(main())
