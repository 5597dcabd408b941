import sys

from firmware_py.entry import main

sys.exit(main())
