import sys

from vdbejax._console import main

sys.exit(main())
