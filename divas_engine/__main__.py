"""``python -m divas_engine`` is the ``divas`` command."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
