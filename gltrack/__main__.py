"""``python -m gltrack`` is the same as the ``gltrack`` console script."""
import sys

from gltrack.cli import main

sys.exit(main())
