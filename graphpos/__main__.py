import sys

from graphpos.cli import main

sys.exit(main())
