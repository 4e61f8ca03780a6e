"""``python -m cvt_ros`` ≡ ``cvt-sim``."""
import sys

from .tools.cli import main

sys.exit(main())
