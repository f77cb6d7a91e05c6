"""``python -m facetransfer COMMAND ...``: the command line (:func:`facetransfer.cli.main.main`),
run as the ``facetransfer`` console script runs it (the same help, errors and exit status)."""

import sys

from facetransfer.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
