import sys

from signsplat.cli import main

sys.exit(main())
