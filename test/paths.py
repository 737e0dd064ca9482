"""Where the tests find the repository and its recordings, from any folder under test/.

One definition: a test file's own ``Path(__file__).parent`` depends on how deep it sits.
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "test" / "data"
