"""``python -m app [--weights DIR] [--host H] [--port P] ...``: the same as ``lsr app``."""

import sys

from lsr.cli import main

sys.exit(main(["app", *sys.argv[1:]]))
