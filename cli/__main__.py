"""``python -m markergraph.cli``: the same as the ``markergraph`` command."""

import sys

from markergraph.cli import main

# Guarded: a spawned process (the plotter, the front end's workers) imports this module again
# as ``__mp_main__``, and must not run the command a second time.
if __name__ == "__main__":
    sys.exit(main())
