"""``python -m marlcrash``: the ``marlcrash`` command (:mod:`marlcrash.cli`), where the console script is not on
``PATH``."""

import sys

from marlcrash.cli import main

if __name__ == "__main__":  # not on import (documentation tools import every module)
    sys.exit(main())
