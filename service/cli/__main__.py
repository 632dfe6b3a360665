"""``python -m service.cli``: the ``oceanlidar`` command line."""

import sys

from service.cli.main import main

sys.exit(main())
