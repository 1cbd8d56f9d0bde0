"""``python -m markergraph.cli``: the same as the ``markergraph`` command."""

import sys

from markergraph.cli import main

sys.exit(main())
