"""``python -m cvt_ros.device`` ≡ ``cvt_node``."""
import sys

from .main import main

sys.exit(main())
