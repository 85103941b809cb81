"""python -m ahrsgen.cli: the `ahrsgen` command."""
import sys

from ahrsgen.cli import main

sys.exit(main())
