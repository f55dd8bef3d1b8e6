"""``python -m mitsnerf.cli``, as ``python -m mitsnerf``."""

import sys

from mitsnerf.cli import main

if __name__ == "__main__":
    sys.exit(main())
