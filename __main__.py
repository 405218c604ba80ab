"""`python -m railswitch`: the command line, as the `railswitch` console script."""
import sys

from railswitch.services.commands.cli import main

sys.exit(main())
