"""Entry point of ``python -m mocapgraph``: runs the ``mocapgraph`` command (see :mod:`.cli`)."""
import sys

from .cli import main

sys.exit(main())
