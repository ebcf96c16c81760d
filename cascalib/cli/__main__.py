import sys

from cascalib.cli import main

sys.exit(main())
