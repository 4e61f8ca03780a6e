"""``python -m cvt_ros`` ≡ ``cvt-sim``."""
import sys

from .cli import main

sys.exit(main())
