"""``python -m microg_env.cli``."""

import sys

from microg_env.cli import main

sys.exit(main())
