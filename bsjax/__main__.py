"""`python -m bsjax …` runs the `bsjax` command (`bsjax.cli.main`)."""

import sys

from bsjax.cli import main

sys.exit(main())
