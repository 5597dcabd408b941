import sys

from sil.entry import main

sys.exit(main())
