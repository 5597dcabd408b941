import sys

from sil.cli import main

sys.exit(main())
