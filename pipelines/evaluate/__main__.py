"""``python -m uss_slam.pipelines.evaluate``: the same as ``uss-eval``."""

import sys

from .cli import main

sys.exit(main())
