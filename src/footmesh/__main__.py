import sys

from footmesh.cli import main

sys.exit(main())
