import sys

from bioslam.cli import main

sys.exit(main())
