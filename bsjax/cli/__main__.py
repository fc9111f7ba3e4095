"""`python -m bsjax.cli …` runs the `bsjax` command."""

import sys

from bsjax.cli import main

sys.exit(main())
