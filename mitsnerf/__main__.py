"""``python -m mitsnerf``: the command line where no console script is installed (a checkout on PYTHONPATH)."""

import sys

from mitsnerf.cli import main

if __name__ == "__main__":
    sys.exit(main())
