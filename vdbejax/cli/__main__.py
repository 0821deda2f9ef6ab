import sys

from vdbejax.cli import main

sys.exit(main())
