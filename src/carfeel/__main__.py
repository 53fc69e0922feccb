"""`python -m carfeel ...`: the command line, as the `carfeel` script runs it."""

from __future__ import annotations

import sys

from carfeel.cli import main

if __name__ == "__main__":
    sys.exit(main())
