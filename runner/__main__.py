"""`python -m simrun`: the same as the `simrun` command."""

import sys

from simrun.cli import main

sys.exit(main())
