import sys

from paper_lle.cli import main

sys.exit(main())
