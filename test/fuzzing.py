"""How many examples the fuzz tests draw.

``make test`` must stay under 8 minutes on two cores: it draws 40 % of the examples each
fuzz test was written and judged with (the same derandomized sequence, cut short);
``FUZZ_EXAMPLES_FACTOR=1`` draws them all (about 100 s more on two cores).
"""

from __future__ import annotations

import os

FACTOR = float(os.environ.get("FUZZ_EXAMPLES_FACTOR", "0.4"))


def examples(full: int) -> int:
    """The share of ``full`` (the judged count) to draw now, at least 100."""
    return max(100, round(full * FACTOR))
