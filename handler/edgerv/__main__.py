import sys

from edgerv.cli import main

sys.exit(main())
