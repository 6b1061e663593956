"""Paths of the checkout the tests run in.

ROOT is the repository; FLOWCLIP_BIN the executable under test ($FLOWCLIP_BIN,
default build/flowclip), which conftest.py hands to the flowclip package's
FlowClipServer through the same variable.
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FLOWCLIP_BIN = Path(os.environ.get("FLOWCLIP_BIN", ROOT / "build" / "flowclip"))
