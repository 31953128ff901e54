"""Fixtures of the hardening tests.

The bad-input corpus builds on the I/O tests' sample files (a hand-built
drive with every channel, a synthetic Plaza .mat): their folder is put on the
import path so the samples are written once, not copied.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))
