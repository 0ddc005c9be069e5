"""``python -m olsbayes``: the command line, the same as the ``olsbayes`` script."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
